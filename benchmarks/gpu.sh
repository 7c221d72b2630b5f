#!/usr/bin/env bash
# Runs benchmark commands on the lent GPU machine (the device tool), one after another, each
# command's output to $OUT/<n>.txt and the benchmarks' results files to $OUT/results/, then
# packs runs/ into $OUT/runs.tgz (checkpoints left out). The copy there has no .git: put the
# commit in front, MJX_HOPPER_COMMIT=abc1234 bash benchmarks/gpu.sh ..., for the results files:
#   bash benchmarks/gpu.sh "python benchmarks/env_throughput.py --devices 1 --label h100"
# With --parallel first, the commands run at once, command n alone on GPU n-1 (a machine of
# several GPUs: each its own GPU, sharing the host's CPUs):
#   bash benchmarks/gpu.sh --parallel "COMMAND ON GPU 0" "COMMAND ON GPU 1"
# The machine has JAX, flax, optax and orbax, but not MuJoCo, MJX or Brax: their wheels are carried
# in .whl/, downloaded once here (Python 3.12, x86-64; add .whl to .git/info/exclude) with
#   pip download --no-deps --only-binary=:all: --python-version 3.12 --platform
#   manylinux_2_28_x86_64 --platform any -d .whl mujoco==4.0.0 mujoco-core==4.0.0
#   mujoco-studio==4.0.0 websockets glfw PyOpenGL mujoco-mjx==3.17.0 brax==0.14.2 jaxopt
#   ml_collections trimesh Flask flask-cors blinker itsdangerous tensorboardX
# MuJoCo's import needs the GL loaders (mujoco.egl), which the machine lacks: carry their Debian
# packages in .gl/ (the device tool's README says how) and they are unpacked here.
set -uo pipefail
parallel=false
if [ "${1:-}" = --parallel ]; then parallel=true; shift; fi
OUT=${OUT:-runs/gpu}
mkdir -p "$OUT" runs
for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
vendor=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
[ -f $vendor ] && export __EGL_VENDOR_LIBRARY_FILENAMES=$vendor
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target /tmp/site \
  .whl/*.whl || exit 1
python3 -m pip install -q --no-index --no-deps --no-build-isolation --no-compile --upgrade \
  --target /tmp/site . || exit 1
export PYTHONPATH=/tmp/site PYTHONUNBUFFERED=1 MJX_HOPPER_RESULTS=$OUT/results
nvidia-smi -L
n=0
for command in "$@"; do
  n=$((n + 1))
  if $parallel; then
    echo "== $n, on GPU $((n - 1)): $command"
    CUDA_VISIBLE_DEVICES=$((n - 1)) bash -c "$command" >"$OUT/$n.txt" 2>&1 &
  else
    echo "== $n: $command"
    bash -c "$command" 2>&1 | tee "$OUT/$n.txt"
  fi
done
wait
$parallel && tail -n 15 "$OUT"/*.txt
tar czf "$OUT/runs.tgz" --exclude checkpoints runs
