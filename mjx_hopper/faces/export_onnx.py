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


def model(policy: export.Policy):
  """The policy's `onnx.ModelProto`."""
  try:
    import onnx
    from onnx import TensorProto, helper, numpy_helper
  except ImportError:
    raise ImportError("writing ONNX needs onnx: in the mjx_hopper checkout, pip install -e "
                      "'.[onnx]'") from None

  nodes, weights = [], []
  names = itertools.count()

  def node(op, *inputs, **attributes):
    out = f"t{next(names)}"
    nodes.append(helper.make_node(op, list(inputs), [out], **attributes))
    return out

  def constant(name, value):
    weights.append(numpy_helper.from_array(np.asarray(value, np.float32), name))
    return name

  def rounded(x, layer):
    if layer["dtype"] != "bfloat16":
      return x
    return node("Cast", node("Cast", x, to=TensorProto.BFLOAT16), to=TensorProto.FLOAT)

  layers, arrays = policy.meta["layers"], policy.arrays
  x = "obs"
  for i, layer in enumerate(layers):
    low = export.round_bfloat16 if layer["dtype"] == "bfloat16" else (lambda v: v)
    x = rounded(node("MatMul", rounded(x, layer), constant(f"w{i}", low(arrays[f"w{i}"]))),
                layer)
    x = node("Add", x, constant(f"b{i}", low(arrays[f"b{i}"])))
    if layer["norm"]:
      x = node("LayerNormalization", x, constant(f"ln{i}_scale", arrays[f"ln{i}_scale"]),
               constant(f"ln{i}_bias", arrays[f"ln{i}_bias"]), axis=-1,
               epsilon=export.LAYER_NORM_EPSILON)
    x = rounded(x, layer)
    if layer["activation"] == "tanh":
      x = node("Tanh", x)
    elif layer["activation"] == "elu":  # its positive part is x, already rounded
      x = rounded(node("Elu", x, alpha=1.0), layer)
    if i + 1 < len(layers):
      x = rounded(x, layers[i + 1])
  if policy.meta["output"] == "tanh":
    x = node("Tanh", x)
  else:
    x = node("Clip", x, constant("low", -1.0), constant("high", 1.0))
  nodes[-1].output[0] = "action"
  size, actions = policy.observation_size, policy.action_size
  graph = helper.make_graph(
      nodes, "mjx_hopper_policy",
      [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", size])],
      [helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", actions])],
      weights)
  out = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)],
                          producer_name="mjx_hopper")
  out.ir_version = 8  # read by ONNX Runtime 1.14 and newer
  helper.set_model_props(out, {key: json.dumps(policy.meta[key]) for key in
                               ("agent", "task", "evaluation", "format") if key in policy.meta})
  onnx.checker.check_model(out)
  return out


def write(path: str, out: str) -> str:
  """Writes the policy exported to `path` as an ONNX model at `out`; returns `out`."""
  proto = model(export.load(path))
  with open(out + ".tmp", "wb") as f:
    f.write(proto.SerializeToString())
  os.replace(out + ".tmp", out)
  return out
