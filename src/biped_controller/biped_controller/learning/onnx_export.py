"""An :class:`~biped_controller.learning.mlp.MlpPolicy` as an ONNX graph, built node by node with the ``onnx``
package from its weights (no tracing: the graph is the maths of ``mlp``'s docstring, float32).

Input ``observation`` float32 (batch, 22), output ``action`` float32 (batch, 6): the deterministic action (the
Gaussian's mean, unclipped), what ``policy.controller.OnnxRunner`` runs. Nodes: Sub, Div (by sqrt(var) + eps,
folded into a constant), Clip, then per layer MatMul, Add and, between layers, Tanh. Opset 17.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from biped_controller.learning.mlp import MlpPolicy

OPSET = 17
INPUT = "observation"
OUTPUT = "action"


def build_model(policy: MlpPolicy, doc: str = ""):
    """The ``onnx.ModelProto`` of ``policy`` (module docstring), checked by ``onnx.checker``."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    def const(name: str, a) -> object:
        return numpy_helper.from_array(np.asarray(a, dtype=np.float32), name)

    inits = [const("obs_mean", policy.obs_mean),
             const("obs_scale", np.sqrt(policy.obs_var) + np.float32(policy.obs_eps)),
             const("clip_lo", -np.float32(policy.obs_clip)), const("clip_hi", np.float32(policy.obs_clip))]
    nodes = [helper.make_node("Sub", [INPUT, "obs_mean"], ["centred"]),
             helper.make_node("Div", ["centred", "obs_scale"], ["scaled"]),
             helper.make_node("Clip", ["scaled", "clip_lo", "clip_hi"], ["h_in"])]
    h = "h_in"
    last = len(policy.weights) - 1
    for k, (w, b) in enumerate(zip(policy.weights, policy.biases)):
        inits += [const(f"W{k}", w), const(f"b{k}", b)]
        nodes.append(helper.make_node("MatMul", [h, f"W{k}"], [f"z{k}_mm"]))
        out = OUTPUT if k == last else f"z{k}"
        nodes.append(helper.make_node("Add", [f"z{k}_mm", f"b{k}"], [out]))
        if k < last:
            nodes.append(helper.make_node("Tanh", [out], [f"h{k}"]))
            h = f"h{k}"
    graph = helper.make_graph(
        nodes, "mlp_policy_mean",
        [helper.make_tensor_value_info(INPUT, TensorProto.FLOAT, ["batch", policy.n_obs])],
        [helper.make_tensor_value_info(OUTPUT, TensorProto.FLOAT, ["batch", policy.n_act])],
        initializer=inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)],
                              producer_name="biped_controller.learning.onnx_export", doc_string=doc)
    model.ir_version = 8          # onnxruntime reads IR 8 at opset 17
    onnx.checker.check_model(model)
    return model


def export(policy: MlpPolicy, path: str | Path, doc: str = "") -> Path:
    """Write ``policy`` as ONNX to ``path`` (parents created); returns the path."""
    import onnx
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(build_model(policy, doc), str(p))
    return p
