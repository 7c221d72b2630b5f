"""An exported policy (`mjx_hopper.faces.export`) as an ONNX model, for ONNX Runtime and the
runtimes that read ONNX.

    from mjx_hopper.faces import export_onnx
    export_onnx.write("policy.npz", "policy.onnx")

The model is built from the file's layers with `onnx.helper`, operator by operator, as
`export.forward` computes them: input "obs" (N, O) float32, output "action" (N, A) float32. A
bfloat16 layer rounds where `export.forward` does, with a Cast to bfloat16 and back.
"""

from __future__ import annotations

import itertools
import json
import os

import numpy as np

from mjx_hopper.faces import export

OPSET = 17  # the first with LayerNormalization


class _Graph:
  """An ONNX graph's nodes and weights, as they are added (each node's output named in turn),
  with onnx's modules."""

  def __init__(self):
    try:
      import onnx
      from onnx import TensorProto, helper, numpy_helper
    except ImportError:
      raise ImportError("writing ONNX needs onnx: in the mjx_hopper checkout, pip install -e "
                        "'.[onnx]'") from None
    self.onnx, self.tensor, self.helper, self._numpy = onnx, TensorProto, helper, numpy_helper
    self.nodes, self.weights, self._names = [], [], itertools.count()

  def node(self, op: str, *inputs: str, **attributes) -> str:
    out = f"t{next(self._names)}"
    self.nodes.append(self.helper.make_node(op, list(inputs), [out], **attributes))
    return out

  def constant(self, name: str, value) -> str:
    self.weights.append(self._numpy.from_array(np.asarray(value, np.float32), name))
    return name

  def rounded(self, x: str, layer: dict) -> str:
    """`x`, rounded to bfloat16 and back where `layer` computes in bfloat16."""
    if layer["dtype"] != "bfloat16":
      return x
    bf16 = self.node("Cast", x, to=self.tensor.BFLOAT16)
    return self.node("Cast", bf16, to=self.tensor.FLOAT)


def _policy_nodes(g: _Graph, policy: export.Policy) -> None:
  """The policy's layers and its output's squashing, from "obs" to "action"."""
  layers, arrays = policy.meta["layers"], policy.arrays
  x = "obs"
  for i, layer in enumerate(layers):
    low = export.round_bfloat16 if layer["dtype"] == "bfloat16" else (lambda v: v)
    x = g.rounded(g.node("MatMul", g.rounded(x, layer), g.constant(f"w{i}", low(arrays[f"w{i}"]))),
                  layer)
    x = g.node("Add", x, g.constant(f"b{i}", low(arrays[f"b{i}"])))
    if layer["norm"]:
      x = g.node("LayerNormalization", x, g.constant(f"ln{i}_scale", arrays[f"ln{i}_scale"]),
                 g.constant(f"ln{i}_bias", arrays[f"ln{i}_bias"]), axis=-1,
                 epsilon=export.LAYER_NORM_EPSILON)
    x = g.rounded(x, layer)
    if layer["activation"] == "tanh":
      x = g.node("Tanh", x)
    elif layer["activation"] == "elu":  # its positive part is x, already rounded
      x = g.rounded(g.node("Elu", x, alpha=1.0), layer)
    if i + 1 < len(layers):
      x = g.rounded(x, layers[i + 1])
  if policy.meta["output"] == "tanh":
    g.node("Tanh", x)
  else:
    g.node("Clip", x, g.constant("low", -1.0), g.constant("high", 1.0))
  g.nodes[-1].output[0] = "action"


def model(policy: export.Policy):
  """The policy's `onnx.ModelProto`."""
  g = _Graph()
  _policy_nodes(g, policy)
  helper, size, actions = g.helper, policy.observation_size, policy.action_size
  graph = helper.make_graph(
      g.nodes, "mjx_hopper_policy",
      [helper.make_tensor_value_info("obs", g.tensor.FLOAT, ["batch", size])],
      [helper.make_tensor_value_info("action", g.tensor.FLOAT, ["batch", actions])],
      g.weights)
  out = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)],
                          producer_name="mjx_hopper")
  out.ir_version = 8  # read by ONNX Runtime 1.14 and newer
  helper.set_model_props(out, {key: json.dumps(policy.meta[key]) for key in
                               ("agent", "task", "evaluation", "format") if key in policy.meta})
  g.onnx.checker.check_model(out)
  return out


def write(path: str, out: str) -> str:
  """Writes the policy exported to `path` as an ONNX model at `out`; returns `out`."""
  proto = model(export.load(path))
  with open(out + ".tmp", "wb") as f:
    f.write(proto.SerializeToString())
  os.replace(out + ".tmp", out)
  return out
