"""lab.step_layer_causes.CommandedDcm: the one change against dcm_wbc is the DCM the layer compares with.

Oracles: on the preferred gait (p = p_d, p' = 0, tau' = 1) the commanded reference's DCM is the preferred
step's table xi_n(tau) (the same quantity, tabulated); at tau' != 1 it differs from it by the CoM velocity's
share, (tau' - 1) x_n' / omega with x_n' = J_G dq/dtau along q_d(p_d, .), computed here from the model."""
from __future__ import annotations

import pytest

from biped_controller.plugin import loop as plugin_loop
from biped_controller.plugin.step_layer import DcmStepLayer, DcmWholeBody

from lab.step_layer_causes import CommandedDcm


@pytest.fixture(scope="module")
def pair():
    setup = plugin_loop.PluginLoop("none").setup
    return DcmWholeBody(setup), CommandedDcm(setup)


def test_on_the_preferred_gait_it_compares_with_the_preferred_dcm(pair):
    base, var = pair
    for tau in (0.0, 0.1, 0.2315, 0.4):
        assert abs(var.layer.xi_n(tau) - base.layer.xi_n(tau)) < 2e-6


def test_a_quicker_reference_moves_the_dcm_it_compares_with(pair):
    base, var = pair
    ref, model, om = var.ref, var.model, var.layer.omega
    var.tau_dot = 1.2
    try:
        for tau in (0.1, 0.3):
            g = ref.at(ref.p_d, tau)
            v = model.com_state(g.q, g.dq_dtau).velocity[0]
            assert var.layer.xi_n(tau) - base.layer.xi_n(tau) == pytest.approx(0.2 * v / om, abs=3e-6)
    finally:
        var.tau_dot = 1.0
    assert type(base.layer) is DcmStepLayer and var.s == base.s       # nothing else changed


def test_the_cell_table_by_hand():
    """Two phases, one direction, one plant: the differences done by hand; a variant measured at one phase."""
    from lab.step_layer_causes import cell_markdown, cell_table
    b = {"forward": {"boundaries": {"0": 100.0, "0.5": 200.0}}}
    slices = {"plants": {"rigid": {"directions": ["forward"], "stats": {
        "dcm_wbc": b, "wbc": {"forward": {"boundaries": {"0": 150.0, "0.5": 180.0}}},
        "both": {"forward": {"boundaries": {"0": 400.0, "0.5": 500.0}}}}}}}
    var = {"rigid": {"boundaries": [{"direction": "forward", "phase": 0.5, "force": 450.0}]}}
    t = cell_table(slices, "dcm_wbc", ("wbc", "both"), {"v": var})
    r0, r1 = t["plants"]["rigid"]["rows"]
    assert (r0["dcm_wbc - wbc"], r0["dcm_wbc - both"], r0["v"]) == (-50.0, -300.0, None)
    assert (r1["dcm_wbc - wbc"], r1["dcm_wbc - both"]) == (20.0, -300.0)
    assert (r1["v - dcm_wbc"], r1["v - wbc"], r1["v - both"]) == (250.0, 270.0, -50.0)
    md = cell_markdown(t)
    assert "| forward | 0.5 | 200 | 180 | 500 | +20 | -300 | 450 | +250 | +270 | -50 |" in md
    st = t["extra_stats"]["v"]["rigid"]["forward"]
    assert st["cells"] == 1 and st["mean"] == 450.0 and st["means"]["wbc"] == 180.0
    assert st["versus"]["both"] == {"ahead": 0, "behind": 1, "equal": 0, "mean_difference": -50.0}
    assert st["versus"]["wbc"]["ahead"] == 1
    t2 = cell_table(slices, "dcm_wbc", ("wbc",), {"dcm_wbc": var}, label="first_law")
    r1 = t2["plants"]["rigid"]["rows"][1]
    assert (r1["first_law"], r1["dcm_wbc"], r1["dcm_wbc - first_law"]) == (200.0, 450.0, 250.0)


def test_maps_on_two_grids_merge_and_must_agree():
    from lab.step_layer_causes import MapMergeError, merge_maps
    a = {"boundaries": [{"direction": "forward", "phase": 0.0, "force": 10.0},
                        {"direction": "forward", "phase": 0.5, "force": 20.0}]}
    b = {"boundaries": [{"direction": "forward", "phase": 0.5, "force": 20.0},
                        {"direction": "forward", "phase": 0.1, "force": 30.0}]}
    assert [x["phase"] for x in merge_maps(a, b)["boundaries"]] == [0.0, 0.1, 0.5]
    b["boundaries"][0]["force"] = 21.0
    with pytest.raises(MapMergeError, match="onset 0.5"):
        merge_maps(a, b)
