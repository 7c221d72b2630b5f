"""The faces floor, the highest: the ways in for people.

`cli` is the `mjx-hopper` command and `notebook` the notebook's helpers; `export` writes a policy
as one NumPy file (the shipped ones are in `pretrained/`), and `export_onnx` that file as ONNX.
"""
