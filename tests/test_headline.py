"""README.md and docs/paper_table.md hold exactly the headline table that ``studies.headline`` builds from the
committed paper's-table files, so neither can drift from the results."""
import json
import shutil

import pytest

from biped_controller.studies import headline
from biped_model.settings import repo_root


@pytest.mark.parametrize("doc", ["README.md", "docs/paper_table.md"])
def test_the_document_holds_the_generated_table(doc):
    text = (repo_root() / doc).read_text()
    assert headline.markdown() in text, f"{doc}: its headline table differs from python -m biped_controller.studies.headline"


def test_a_changed_file_changes_the_table_and_a_missing_row_is_named(tmp_path):
    """Negative controls: the table follows the files (one figure changed shows), and a file without a row is an
    error naming the file and the row."""
    (tmp_path / "results").mkdir()
    shutil.copytree(repo_root() / "results" / "paper_table", tmp_path / "results" / "paper_table")
    before = headline.markdown(tmp_path)
    path = headline.table_file("mujoco", "paper", tmp_path)
    d = json.loads(path.read_text())
    d["modes"]["both"]["max_force"] = 1.5
    path.write_text(json.dumps(d))
    after = headline.markdown(tmp_path)
    assert after != before and "| both | 650 |" in after and " 1.5 |" in after
    del d["modes"]["wbc"]
    path.write_text(json.dumps(d))
    with pytest.raises(headline.HeadlineError, match=r"mujoco_paper\.json has no row 'wbc'"):
        headline.markdown(tmp_path)
