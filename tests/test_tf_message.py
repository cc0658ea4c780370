"""The simulator node's /tf message is updated in place for speed: it must equal a freshly built one
at every state (stamps, torso translation, every rotation), seeded random states."""
import numpy as np

from biped_model.description import load_description, make_urdf
from biped_sim.graph.simulator_node import TransformBuilder, stamp_of


def test_in_place_tf_equals_fresh_message():
    urdf = make_urdf(load_description())
    reused = TransformBuilder(urdf)
    rng = np.random.default_rng(3)
    for k in range(50):
        x = rng.uniform(-1.0, 1.0, 9)
        stamp = stamp_of(k * 1e-3)
        m = reused.message(stamp, x)
        fresh = TransformBuilder(urdf).message(stamp, x)
        assert m == fresh, k
        assert m.transforms[0].transform.translation.x == x[0]
    # a negative control: a different state gives a different message
    assert reused.message(stamp, x + 0.1) != TransformBuilder(urdf).message(stamp, x)
