#!/usr/bin/env bash
# The GPU runs behind BENCHMARKS.md and docs/benchmark-history.md, in the batches the device
# tool runs them (each call is at most 10 minutes). On the device machine, from the repository
# root, with the wheels that cannot be downloaded there carried in .whl/:
#   bash benchmarks/gpu_session.sh install-and-tune   # learner throughput, agent tests, tuning
#   bash benchmarks/gpu_session.sh ddpg mpo           # learning, 3 seeds of each, all at once
#   bash benchmarks/gpu_session.sh dmpo cpu-tune      # ... and D4PG settings for the 2-core CPU
#   bash benchmarks/gpu_session.sh mpo-tune           # MPO/DMPO std constraints, CPU settings
#   bash benchmarks/gpu_session.sh mpo dmpo mpo-cpu-seed2  # their gpu presets, once retuned
#   bash benchmarks/gpu_session.sh mpo-acme-std       # acme's std constraint, as a baseline
#   bash benchmarks/gpu_session.sh humanoid-stability # cheaper Humanoid solver settings
#   bash benchmarks/gpu_session.sh humanoid-ls        # ... with fewer line-search steps
#   bash benchmarks/gpu_session.sh humanoid-shipped   # the shipped Humanoid's stability, 4 seeds
#   bash benchmarks/gpu_session.sh humanoid-before    # ... and the model it replaced, 4 seeds
#   bash benchmarks/gpu_session.sh humanoid-capture   # its GPU rows; non-finite states saved
#   bash benchmarks/gpu_session.sh humanoid-limits    # joint-limit settings, screened
#   bash benchmarks/gpu_session.sh humanoid-armature  # hinge armature, screened
#   bash benchmarks/gpu_session.sh humanoid-confirm   # the Humanoid as shipped: GPU rows, stability
#   bash benchmarks/gpu_session.sh mpo-pair0          # MPO and DMPO seed 0, two runs on the GPU
#   bash benchmarks/gpu_session.sh sweep-throughput   # sweeps of 1 to 64 members, alone on the GPU
#   bash benchmarks/gpu_session.sh peers              # our D4PG, Brax SAC and PPO (tuned), one run
#   bash benchmarks/gpu_session.sh scaling            # the trainer from 512 to 16k envs, alone
#   bash benchmarks/gpu_session.sh sweep-collect      # a 16-member sweep's env steps alone
#   bash benchmarks/gpu_session.sh screen-hopper      # GPU trainer layouts and options, 4 at once
#   bash benchmarks/gpu_session.sh screen-humanoid    # the Humanoid's layouts and options, with Hopper's
#   bash benchmarks/gpu_session.sh humanoid-solve     # the Humanoid's solve, its share of a step
#   bash benchmarks/gpu_session.sh tts-Hopper         # benchmarks/time_to_score.py Hopper --kind gpu
#   bash benchmarks/gpu_session.sh tts-Walker2D tts-Ant   # ... two robots sharing the GPU
#   bash benchmarks/gpu_session.sh tts-Hopper wait tts-Ant  # ... one after the other
#   bash benchmarks/gpu_session.sh hopper-cold        # Hopper's seeds each compiled afresh
#   bash benchmarks/gpu_session.sh cold-Hopper:1.6    # ... alone, no autotuning run after them
#   bash benchmarks/gpu_session.sh cpu-tune2          # CPU layouts for Hopper, emulated
#   bash benchmarks/gpu_session.sh cpu-tune3          # ... with smaller networks
#   bash benchmarks/gpu_session.sh cpu-tune4 wait     # ... learning rates, n-step, target copies
#   bash benchmarks/gpu_session.sh member-layout      # members' envs nested or flat, alone
#   bash benchmarks/gpu_session.sh collect-parts      # a sweep's collection, part by part, alone
#   bash benchmarks/gpu_session.sh cpu60-Walker2D cpu60-Ant   # 60-minute CPU runs, emulated
#   bash benchmarks/gpu_session.sh compile-parts      # Hopper's first minute, part by part
#   bash benchmarks/gpu_session.sh sweep-precision    # a 16-member sweep, TF32 against bf16
#   bash benchmarks/gpu_session.sh sweep-triton       # sweeps with cuBLAS against Triton GEMMs
#   bash benchmarks/gpu_session.sh cheetah-explore    # HalfCheetah's stuck seed, wider noise
#   bash benchmarks/gpu_session.sh hopper-seeds wait  # Hopper's 5 seeds, preset and wider noise
#   bash benchmarks/gpu_session.sh cheetah-cpu-explore wait  # HalfCheetah's cpu preset, 3 noises
#   bash benchmarks/gpu_session.sh projection-cost cpu-tune5 wait  # D4PG's projection, 2 ways;
#                                                     # the cpu layout with an action penalty
#   bash benchmarks/gpu_session.sh cpu-tune6 wait     # ... around cpu-tune5's best
#   bash benchmarks/gpu_session.sh cpu-tune7 wait     # the new Hopper cpu preset's seeds, 3 variants
#   bash benchmarks/gpu_session.sh hopper-pen wait    # Hopper's gpu preset with an action penalty
#   bash benchmarks/gpu_session.sh walker-pen wait    # ... and Walker2D's, with and without
#   bash benchmarks/gpu_session.sh sweep-profile      # a sweep's iteration, kernel by kernel
#   bash benchmarks/gpu_session.sh hopper-lr wait     # Hopper's gpu preset at higher learning rates
#   bash benchmarks/gpu_session.sh hopper-bf16 wait   # ... at 1e-3 in bfloat16, and more seeds
#   bash benchmarks/gpu_session.sh bf16-robots wait   # Walker2D's and the Humanoid's in bfloat16
# Every run of a call shares the one GPU (XLA_PYTHON_CLIENT_MEM_FRACTION=0.1 each). The device
# tool's calls run it as
#   timeout 570 bash benchmarks/gpu_session.sh PHASES > $OUT/session.log 2>&1;
#   tar czf $OUT/results.tgz --exclude checkpoints -C /tmp/gpu_runs .
# so that a call that runs out of time still brings back what it printed and wrote.
# The runs write to $WORK; $OUT (default runs/gpu) gets the printed tables and results.tgz (every
# run's summary, curves and log, without checkpoints).
set -uo pipefail
OUT=${OUT:-runs/gpu}
WORK=${WORK:-/tmp/gpu_runs}
mkdir -p "$OUT" "$WORK"
python3 -m pip install -q --no-deps .whl/*.whl >/dev/null 2>&1
python3 -m pip install -q --no-deps --no-build-isolation -e . >/dev/null 2>&1
nvidia-smi -L
export XLA_PYTHON_CLIENT_MEM_FRACTION=0.1
learn() {  # learn NAME ARGS...: one learning benchmark in the background, logged to $WORK/NAME.txt
  local name=$1; shift
  python3 benchmarks/learning.py --env Hopper --cpu-devices 1 --out "$WORK/$name" "$@" \
    > "$WORK/$name.txt" 2>&1 &
}
GPU_TRAIN=(--num-envs 512 --unroll-length 4 --batch-size 1024 --replay-ratio 4 --min-replay 20000
           --chunk 25 --eval-every 200000)
stable() {  # stable VARIANT [SEED [ENVS]]: humanoid_options.py's stability check in the
  # background, ENVS (256) envs x 10,000 random-action steps, logged to
  # $WORK/humanoid_VARIANT_seedSEED.txt; the non-finite steps' starting states go to
  # $WORK/nonfinite_VARIANT_seedSEED.npz (benchmarks/research/replay_nonfinite.py). It stops
  # after the chunk that passes $STABLE_SECONDS (540).
  local v=$1 seed=${2:-0} envs=${3:-256}
  local log="$WORK/humanoid_$(echo "$v" | tr ' /' '__')_seed$seed.txt"
  timeout 580 python3 benchmarks/research/humanoid_options.py --stability 10000 --num-envs "$envs" \
    --variants "$v" --seed "$seed" --max-seconds "${STABLE_SECONDS:-540}" \
    --dump "$WORK/nonfinite" > "$log" 2>&1 &
}
humanoid_gpu_rows() {  # the Humanoid's GPU throughput, alone on the GPU, to $WORK/humanoid_gpu.*
  XLA_PYTHON_CLIENT_MEM_FRACTION=0.6 timeout 150 python3 benchmarks/env_throughput.py \
    --envs Humanoid --batches 4096,32768 --devices 1 --steps-total 2000000 \
    --json "$WORK/humanoid_gpu.json" > "$WORK/humanoid_gpu.txt" 2>&1
}
tune() {  # tune NAME ARGS...: the phase's time_to_score command T with ARGS, in the background,
  # labelled NAME, logged to $WORK/NAME.txt
  local name=$1; shift
  timeout 560 python3 "${T[@]}" --out "$WORK/$name" --label "$name" "$@" > "$WORK/$name.txt" 2>&1 &
}
# The phases run before the Humanoid got its hinge armature (0.02), solver tolerance (1e-4) and
# 3/3 solve start from the model they ran on (4/4 then), so that they rerun what
# docs/benchmark-history.md records for them; a variant's own words come after it and win.
BEFORE_ARMATURE="4/4 arm=0 tol=1e-8"
# Hopper's cpu preset before its action penalty (2026-11-25), which the cpu-tune phases up to
# cpu-tune6 ran as "the preset"; their own --set flags come after it and win.
OLD_HOPPER_CPU=(--set action_penalty=0 --set learning_rate=3e-4 --set sigma=0.3 --set sigma_min=None)
# Mixed exploration noise, stds 0.05 to 0.4 over the envs (the gpu presets').
MIXED=(--set sigma=0.4 --set sigma_min=0.05)
# The 2-core CPU's settings (TrainConfig's defaults), for runs that stand in for CPU runs.
CPU_TRAIN=(--preset cpu --minutes 8 --chunk 25 --min-replay 20000 --target 2000 --eval-every 200000
           --num-envs 512 --batch-size 256 --replay-ratio 4)

for phase in "$@"; do
  case $phase in
    install-and-tune)
      timeout 200 python3 benchmarks/learner_throughput.py --devices 1 --agents d4pg,ddpg,mpo,dmpo \
        --json "$WORK/learner_gpu.json" > "$WORK/learner_gpu.md" 2> "$WORK/learner_gpu.err"
      cat "$WORK/learner_gpu.md"
      export XLA_PYTHON_CLIENT_MEM_FRACTION=0.12
      # D4PG's cpu preset with the CPU's candidate batch layouts, 5 minutes each.
      T=(--agent d4pg --preset cpu --seeds 0 --minutes 5 --chunk 25 --min-replay 20000 --target 2000)
      learn tune_e64_b256_r8 "${T[@]}" --num-envs 64 --batch-size 256 --replay-ratio 8 --eval-every 50000
      learn tune_e256_b256_r4 "${T[@]}" --num-envs 256 --batch-size 256 --replay-ratio 4 --eval-every 100000
      learn tune_e512_b512_r4 "${T[@]}" --num-envs 512 --batch-size 512 --replay-ratio 4 --eval-every 100000
      # The new agents, one seed each, to catch a learner that does not learn.
      for agent in ddpg mpo dmpo; do
        learn check_$agent --agent $agent --preset gpu --seeds 0 --minutes 5 --target 2500 "${GPU_TRAIN[@]}"
      done
      JAX_PLATFORMS=cpu timeout 400 python3 -m pytest -q -x -p no:cacheprovider tests/test_mpo.py \
        tests/test_dpg.py > "$WORK/pytest.txt" 2>&1
      tail -3 "$WORK/pytest.txt"
      ;;
    ddpg|mpo|dmpo|d4pg)  # 3 seeds of this agent's gpu preset, 8.5 minutes each
      learn learning_$phase --agent $phase --preset gpu --seeds 0,1,2 --minutes 8.5 --target 2500 \
        "${GPU_TRAIN[@]}"
      ;;
    cpu-tune)
      # Return against env steps of D4PG settings the 2-core CPU could afford (its cost per env
      # step and per update comes from benchmarks/env_throughput.py and learner_throughput.py).
      T=(--agent d4pg --seeds 0 --minutes 8.5 --chunk 25 --min-replay 20000 --target 2000
         --eval-every 200000)
      learn tune_cpu_e512_b512_r4 "${T[@]}" --preset cpu --num-envs 512 --batch-size 512 --replay-ratio 4
      learn tune_cpu_e512_b256_r4 "${T[@]}" --preset cpu --num-envs 512 --batch-size 256 --replay-ratio 4
      learn tune_cpu_e1024_b1024_r4 "${T[@]}" --preset cpu --num-envs 1024 --batch-size 1024 --replay-ratio 4
      learn tune_gpu_e512_b512_r2 "${T[@]}" --preset gpu --num-envs 512 --batch-size 512 --replay-ratio 2
      ;;
    mpo-tune)
      # MPO and DMPO with the CPU's settings and looser std constraints (2 seeds each): acme's
      # eps_std 1e-6 with its std dual starting at 1000 keeps the policy's std near 0.6.
      T=("${CPU_TRAIN[@]}" --seeds 0,1)
      for agent in mpo dmpo; do
        learn tune_${agent}_std1e-5 --agent $agent "${T[@]}" --set epsilon_stddev=1e-5 \
          --set init_log_alpha_stddev=10.0
        learn tune_${agent}_std1e-4 --agent $agent "${T[@]}" --set epsilon_stddev=1e-4 \
          --set init_log_alpha_stddev=10.0
      done
      ;;
    mpo-cpu-seed2)
      # The third seed of mpo-tune's eps_std 1e-5 (now the presets' value), same settings.
      T=("${CPU_TRAIN[@]}" --seeds 2)
      for agent in mpo dmpo; do learn tune_${agent}_std1e-5_seed2 --agent $agent "${T[@]}"; done
      ;;
    mpo-acme-std)
      # The baseline for mpo-tune: acme's std constraint with the same CPU settings, 3 seeds;
      # and eps_std 3e-6 between the two (2 seeds of MPO).
      T=("${CPU_TRAIN[@]}")
      for agent in mpo dmpo; do
        learn tune_${agent}_std1e-6 --agent $agent "${T[@]}" --seeds 0,1,2 \
          --set epsilon_stddev=1e-6 --set init_log_alpha_stddev=1000.0
      done
      learn tune_mpo_std3e-6 --agent mpo "${T[@]}" --seeds 0,1 --set epsilon_stddev=3e-6
      ;;
    humanoid-stability)
      # Cheaper Humanoid solves through the stability check, each variant in its own process.
      for v in "all 4/8" "all 3/6" "all 3/4" "all 4/4" "all 2/8" "legs 3/6" "legs 2/6" \
               "all dt3 4/8"; do
        stable "$BEFORE_ARMATURE $v"
      done
      ;;
    humanoid-shipped)
      # The shipped Humanoid (4/4, floor contacts for the legs) on four seeds of the stability
      # check, four processes at once (seed 1 is in docs/benchmark-history.md's table already).
      for seed in 0 2 3 4; do stable "$BEFORE_ARMATURE" $seed; done
      ;;
    humanoid-before)
      # The Humanoid as shipped before (4/8, every part touching the floor), on the seeds the
      # shipped model's check used, as the baseline for its non-finite states.
      for seed in 1 2 3 4; do stable "$BEFORE_ARMATURE all 4/8" $seed; done
      ;;
    mpo-pair[0-9])
      # MPO and DMPO's gpu presets, one seed, only the two of them on the GPU: nearer to "one
      # GPU" than the six- to eight-way shared runs above. Each stops at 2,500.
      seed=${phase#mpo-pair}
      for agent in mpo dmpo; do
        learn pair_${agent}_$seed --agent $agent --preset gpu --seeds $seed --minutes 9.2 \
          --target 2500 --stop-at-target "${GPU_TRAIN[@]}"
      done
      ;;
    humanoid-capture)
      # The shipped Humanoid: its GPU throughput alone on the GPU, then two seeds of 4,096 envs x
      # 10,000 random-action steps (16 times the stability check's 256 envs each), saving the
      # state before each non-finite step for benchmarks/research/replay_nonfinite.py.
      humanoid_gpu_rows
      STABLE_SECONDS=360
      for seed in 10 11; do stable "$BEFORE_ARMATURE" $seed 4096; done
      ;;
    humanoid-limits)
      # The captured non-finite states were blow-ups after joints had crept far past their
      # limits (a hip 0.5 rad past, a knee 1.07); limits with stiffness or harder impedance,
      # 2,048 envs x 10,000 random-action steps each, four at once.
      STABLE_SECONDS=420
      # (As run on 2026-11-23 the variants were split at their commas: what ran was limimp=0.99
      # (d0 only), limref=-400 and limref=-4000 (stiffness; damping stays 400), and limref=0.02.)
      for v in "limimp=0.99,0.99" "limref=-400,-400" "limref=-4000,-400" "limref=0.02,1"; do
        stable "$BEFORE_ARMATURE $v" 12 2048
      done
      ;;
    humanoid-armature)
      # Armature on the hinges: the hips' three hinges meet at one point, and a hip_z past its
      # limit nears the pose where hip_x and hip_y line up and the mass matrix is singular.
      STABLE_SECONDS=420
      for a in 0.005 0.01 0.02 0.05; do stable "4/4 arm=$a tol=1e-8" 12 2048; done
      ;;
    humanoid-confirm)
      # The Humanoid as shipped (run first with 4/4, then with 3/3): its GPU throughput alone on
      # the GPU, then 4,096 envs x 10,000 steps (seed 10, as humanoid-capture) beside the
      # stability check itself (256 envs x 10,000 steps) on seeds 0, 1 and 2.
      humanoid_gpu_rows
      STABLE_SECONDS=420
      stable shipped 10 4096
      for seed in 0 1 2; do stable shipped $seed; done
      ;;
    sweep-throughput)
      # Sweeps of 1 to 64 D4PG members (gpu preset, 512 envs and batch 1,024 each), alone on
      # the GPU, each size in a fresh process (benchmarks/sweep_throughput.py).
      XLA_PYTHON_CLIENT_MEM_FRACTION=0.9 timeout 560 python3 benchmarks/sweep_throughput.py \
        --preset gpu --num-envs 512 --batch-size 1024 --replay-size 1000000 --chunk 10 \
        --chunks 3 --members 1,4,16,64 --cpu-devices 1 --out "$WORK/sweep_throughput_gpu.json" \
        > "$WORK/sweep_throughput_gpu.txt" 2>&1
      cat "$WORK/sweep_throughput_gpu.txt"
      cp "$WORK/sweep_throughput_gpu.json" "$OUT/"
      ;;
    peers)
      # Our D4PG (gpu preset), Brax SAC and Brax PPO on our Hopper, all in one run on the GPU,
      # with Brax's reward scaling and discount tuned in the same run: 9 runs at once, 7.5 min
      # each (benchmarks/peers.py).
      timeout 590 python3 benchmarks/peers.py --minutes 7.5 --grace 30 --label h100 \
        --out "$WORK/peers" --grid sac:reward_scaling=1,10 --grid sac:discounting=0.99,0.997 \
        --grid ppo:reward_scaling=1,10 --grid ppo:discounting=0.97,0.99 \
        > "$WORK/peers.txt" 2>&1
      tail -30 "$WORK/peers.txt"
      cp benchmarks/results/peers_h100.json "$OUT/" 2>/dev/null
      ;;
    scaling)
      # The whole trainer (benchmarks/trainer_scaling.py) from 512 to 16,384 envs at batches up
      # to 65,536, alone on the GPU (about 20 s of compiling per point); then the Humanoid's
      # physics alone from 512 to 16,384 envs.
      export XLA_PYTHON_CLIENT_MEM_FRACTION=0.9
      S=(--updates 2 --chunk 20 --chunks 3 --json "$WORK/scaling.json")
      timeout 170 python3 benchmarks/trainer_scaling.py --env Hopper "${S[@]}" \
        --points 512:1024,4096:8192,16384:32768,16384:65536
      timeout 120 python3 benchmarks/env_throughput.py --envs Humanoid \
        --batches 512,4096,16384 --devices 1 --steps-total 1000000 \
        --json "$WORK/humanoid_physics.json"
      cp "$WORK"/scaling.json "$WORK"/humanoid_physics.json "$OUT/"
      ;;
    sweep-collect)
      # A 1- and a 16-member sweep with learning off: the env steps, actions and replay inserts
      # alone, against sweep-throughput's whole iterations (issue 16).
      XLA_PYTHON_CLIENT_MEM_FRACTION=0.9 timeout 100 python3 benchmarks/sweep_throughput.py \
        --preset gpu --num-envs 512 --batch-size 1024 --replay-size 1000000 --chunk 10 \
        --chunks 3 --members 1,16 --cpu-devices 1 --collect-only \
        --out "$WORK/sweep_collect_gpu.json"
      cp "$WORK/sweep_collect_gpu.json" "$OUT/"
      ;;
    screen-hopper)
      # D4PG on Hopper, four layouts and options at once (0.2 of the GPU's memory each),
      # ${SCREEN_MINUTES:-3} min: the old gpu preset's layout (512 envs, unroll 4, batch 1,024,
      # ratio 4) with one critic and sigma 0.3; 2,048 envs stepped once per iteration with 8
      # updates of 8,192 (ratio 32), with clipped double Q and mixed noise, and without; and
      # 1,024 envs with the same updates (ratio 64).
      export XLA_PYTHON_CLIENT_MEM_FRACTION=0.2
      T=(--agent d4pg --preset gpu --seeds 0 --minutes "${SCREEN_MINUTES:-3}" --target 2500
         --eval-every 500000)
      PLAIN=(--set num_critics=1 --set sigma=0.3 --set sigma_min=None)
      BIG=(--unroll-length 1 --min-replay 40960 --chunk 50 --batch-size 8192)
      learn screen_old_layout "${T[@]}" "${GPU_TRAIN[@]}" "${PLAIN[@]}" --eval-every 500000
      learn screen_e2k_r32 "${T[@]}" "${BIG[@]}" --num-envs 2048 --replay-ratio 32
      learn screen_e2k_r32_plain "${T[@]}" "${BIG[@]}" --num-envs 2048 --replay-ratio 32 \
        "${PLAIN[@]}"
      learn screen_e1k_r64 "${T[@]}" "${BIG[@]}" --num-envs 1024 --replay-ratio 64
      ;;
    scaling-rest)
      # The scaling phase's points that its first call had no time for.
      export XLA_PYTHON_CLIENT_MEM_FRACTION=0.9
      timeout 250 python3 benchmarks/trainer_scaling.py --env Hopper --updates 2 --chunk 20 \
        --chunks 3 --json "$WORK/scaling.json" --points 16384:32768,16384:65536,2048:8192
      cp "$WORK"/scaling.json "$OUT/"
      ;;
    screen-humanoid)
      # Seven runs at once (0.13 of the GPU's memory each). Hopper for 3 min, in the layout that
      # learned fastest in screen-hopper (1,024 envs stepped once per iteration, 8 updates of
      # 8,192: ratio 64), seed 0 (stuck there with both options), with one option at a time:
      # neither, clipped double Q alone, mixed noise alone. The Humanoid for
      # ${SCREEN_MINUTES:-7} min: that layout with neither option and with both; 4,096 envs with
      # 2 updates of 32,768 (ratio 16) with neither; and the first with FastTD3's larger networks.
      export XLA_PYTHON_CLIENT_MEM_FRACTION=0.13
      PLAIN=(--set num_critics=1 --set sigma=0.3 --set sigma_min=None)
      CDQ_ONLY=(--set num_critics=2 --set sigma=0.3 --set sigma_min=None)
      MIXED_ONLY=(--set num_critics=1 --set sigma=0.4 --set sigma_min=0.05)
      BOTH=(--set num_critics=2 --set sigma=0.4 --set sigma_min=0.05)
      E1K=(--num-envs 1024 --unroll-length 1 --min-replay 40960 --chunk 50 --batch-size 8192
           --replay-ratio 64 --eval-every 500000)
      T=(--agent d4pg --preset gpu --seeds 0 --minutes 3 --target 2500)
      learn hop_e1k_r64_plain "${T[@]}" "${E1K[@]}" "${PLAIN[@]}"
      learn hop_e1k_r64_cdq "${T[@]}" "${E1K[@]}" "${CDQ_ONLY[@]}"
      learn hop_e1k_r64_mixed "${T[@]}" "${E1K[@]}" "${MIXED_ONLY[@]}"
      H=(--env Humanoid --agent d4pg --preset gpu --seeds 0 --minutes "${SCREEN_MINUTES:-7}"
         --target 2500)
      learn hum_e1k_r64_plain "${H[@]}" "${E1K[@]}" "${PLAIN[@]}"
      learn hum_e1k_r64_both "${H[@]}" "${E1K[@]}" "${BOTH[@]}"
      learn hum_e4k_b32k_r16_plain "${H[@]}" "${PLAIN[@]}" --num-envs 4096 --unroll-length 1 \
        --min-replay 40960 --chunk 50 --batch-size 32768 --replay-ratio 16 --eval-every 1000000
      learn hum_e1k_r64_plain_big "${H[@]}" "${E1K[@]}" "${PLAIN[@]}" \
        --set "critic_layers=(1024,512,256)" --set "policy_layers=(512,256,128)"
      ;;
    humanoid-solve)
      # What the Humanoid's step spends in the constraint solve, alone on the GPU at 16,384
      # envs: the shipped model (3 Newton iterations, 3 line-search steps) against 1 and 1.
      XLA_PYTHON_CLIENT_MEM_FRACTION=0.9 timeout 110 python3 \
        benchmarks/research/humanoid_options.py --num-envs 16384 --steps 100 \
        --variants "shipped;1/1" > "$WORK/humanoid_solve.txt" 2>&1
      cat "$WORK/humanoid_solve.txt"
      ;;
    wait)  # waits for the runs started before it (tts phases run in the background)
      wait
      ;;
    tts-*)
      # benchmarks/time_to_score.py ROBOT --kind gpu (3 seeds one after another, each until it
      # reaches the robot's target or its budget runs out; the rows of 2026-11-24 ran them at
      # once, TTS_ARGS=--at-once), in the background; the tts phases
      # of one call share the GPU, each with an even share of its memory. tts-ROBOT:M gives it
      # a budget of M minutes instead of its preset's; TTS_ARGS adds flags.
      robot=${phase#tts-}; minutes=
      if [[ $robot == *:* ]]; then minutes="--minutes ${robot#*:}"; robot=${robot%%:*}; fi
      n=$(printf '%s\n' "$@" | grep -c '^tts-')
      XLA_PYTHON_CLIENT_MEM_FRACTION=$(python3 -c "print(round(0.9 / $n, 3))") timeout 560 \
        python3 benchmarks/time_to_score.py "$robot" --kind gpu --cpu-devices 1 \
        --out "$WORK/tts_$robot" $minutes ${TTS_ARGS:-} > "$WORK/tts_$robot.txt" 2>&1 &
      ;;
    hopper-cold)
      # time_to_score.py Hopper as a first run on a new machine: every seed compiled afresh (no
      # compile cache); then seed 0 again with XLA's GPU autotuning off, for its compile time.
      T=(benchmarks/time_to_score.py Hopper --kind gpu --cpu-devices 1 --no-compile-cache
         --minutes 1.8)
      XLA_PYTHON_CLIENT_MEM_FRACTION=0.9 timeout 380 python3 "${T[@]}" \
        --out "$WORK/tts_Hopper_cold" > "$WORK/tts_Hopper_cold.txt" 2>&1
      XLA_FLAGS=--xla_gpu_autotune_level=0 XLA_PYTHON_CLIENT_MEM_FRACTION=0.9 timeout 145 \
        python3 "${T[@]}" --seeds 0 --label "autotune off" --out "$WORK/tts_Hopper_cold_noautotune" \
        > "$WORK/tts_Hopper_cold_noautotune.txt" 2>&1
      ;;
    cold-*)
      # time_to_score.py ROBOT as a first run on a new machine: its seeds one after another,
      # each compiled afresh (no compile cache), alone on the GPU; cold-ROBOT:M gives each
      # seed M minutes instead of the preset's. TTS_ARGS adds flags.
      robot=${phase#cold-}; minutes=
      if [[ $robot == *:* ]]; then minutes="--minutes ${robot#*:}"; robot=${robot%%:*}; fi
      XLA_PYTHON_CLIENT_MEM_FRACTION=0.9 timeout 560 python3 benchmarks/time_to_score.py \
        "$robot" --kind gpu --cpu-devices 1 --no-compile-cache $minutes ${TTS_ARGS:-} \
        --out "$WORK/cold_$robot" > "$WORK/cold_$robot.txt" 2>&1
      tail -25 "$WORK/cold_$robot.txt"
      ;;
    cpu-tune2)
      # D4PG's cpu preset on Hopper with more updates per env step and mixed noise, 2 seeds each
      # (one program), until 2,000 or 5M env steps, six at once: the env steps and updates each
      # needs, which the 2-core CPU's costs per env step and per update turn into its minutes.
      export XLA_PYTHON_CLIENT_MEM_FRACTION=0.15
      T=(benchmarks/time_to_score.py Hopper --kind cpu "${OLD_HOPPER_CPU[@]}"
         --cpu-devices 1 --seeds 0,1 --at-once
         --minutes 8 --env-steps 5000000)
      tune cpu_r4
      tune cpu_r4_mixed "${MIXED[@]}"
      tune cpu_r8 --train replay_ratio=8
      tune cpu_r8_mixed --train replay_ratio=8 "${MIXED[@]}"
      tune cpu_r16 --train replay_ratio=16
      tune cpu_r8_b512 --train replay_ratio=8 --train batch_size=512
      ;;
    cpu-tune3)
      # cpu-tune2's best (mixed noise) with the networks halved in width, 128-128 (about a
      # third of an update's cost on the CPU), at ratios 4, 8 and 16; and at full width,
      # ratio 16 with mixed noise and ratio 8 with batch 128. 2 seeds each, six at once.
      export XLA_PYTHON_CLIENT_MEM_FRACTION=0.15
      T=(benchmarks/time_to_score.py Hopper --kind cpu "${OLD_HOPPER_CPU[@]}"
         --cpu-devices 1 --seeds 0,1 --at-once
         --minutes "${TUNE_MINUTES:-8}" --env-steps 5000000 "${MIXED[@]}")
      SMALL=(--set "policy_layers=(128,128)" --set "critic_layers=(128,128)")
      tune cpu_r4_mixed_w128 "${SMALL[@]}"
      tune cpu_r8_mixed_w128 --train replay_ratio=8 "${SMALL[@]}"
      tune cpu_r16_mixed_w128 --train replay_ratio=16 "${SMALL[@]}"
      tune cpu_r16_mixed --train replay_ratio=16
      tune cpu_r8_mixed_b128 --train replay_ratio=8 --train batch_size=128
      tune cpu_r8_mixed_w128_b512 --train replay_ratio=8 --train batch_size=512 "${SMALL[@]}"
      ;;
    cpu-tune4)
      # cpu-tune2's best per CPU second at full width (ratio 4, mixed noise 0.05 to 0.4) against
      # faster learning rates, 3-step returns, a target copied every 20 updates, and ratio 2
      # with a learning rate of 1e-3 (about 0.7 of ratio 4's CPU cost per env step). 2 seeds
      # each (one program), until 2,000 or 5M env steps, six at once.
      export XLA_PYTHON_CLIENT_MEM_FRACTION=0.15
      T=(benchmarks/time_to_score.py Hopper --kind cpu "${OLD_HOPPER_CPU[@]}"
         --cpu-devices 1 --seeds 0,1 --at-once
         --minutes "${TUNE_MINUTES:-8.6}" --env-steps 5000000 "${MIXED[@]}")
      tune cpu_r4_mixed
      tune cpu_r4_mixed_lr6e-4 --set learning_rate=6e-4
      tune cpu_r4_mixed_lr1e-3 --set learning_rate=1e-3
      tune cpu_r4_mixed_n3 --set n_step=3
      tune cpu_r4_mixed_target20 --set target_update_period=20
      tune cpu_r2_mixed_lr1e-3 --train replay_ratio=2 --set learning_rate=1e-3
      ;;
    projection-cost)
      # D4PG's categorical projection as scatter-adds against a fused dense sum, alone and in
      # an update, up to a 16-member sweep's 131k samples per update (alone on the GPU).
      XLA_PYTHON_CLIENT_MEM_FRACTION=0.6 timeout 120 python3 benchmarks/research/projection_cost.py \
        --batches 1024,8192,32768,131072 --json "$WORK/projection_cost_gpu.json" \
        > "$WORK/projection_cost_gpu.txt" 2>&1
      cat "$WORK/projection_cost_gpu.txt"
      ;;
    cpu-tune5)
      # The cpu layout's policy saturates early on some seeds (its tanh pinned at +-1 within the
      # first 512 updates, the policy gradient about 0.001 until 500k env steps): the preset
      # then against a penalty on the pre-tanh actions of 0.01, 0.1 and 1, and 0.1 with
      # mixed noise, at learning rates 3e-4 and 1e-3. 4 seeds each (one program), until 2,000
      # or 5M env steps, six at once.
      export XLA_PYTHON_CLIENT_MEM_FRACTION=0.15
      T=(benchmarks/time_to_score.py Hopper --kind cpu "${OLD_HOPPER_CPU[@]}"
         --cpu-devices 1 --seeds 0,1,2,3 --at-once
         --minutes "${TUNE_MINUTES:-7}" --env-steps 5000000)
      tune cpu_r4
      tune cpu_r4_pen0.01 --set action_penalty=0.01
      tune cpu_r4_pen0.1 --set action_penalty=0.1
      tune cpu_r4_pen1 --set action_penalty=1
      tune cpu_r4_mixed_pen0.1 --set action_penalty=0.1 "${MIXED[@]}"
      tune cpu_r4_mixed_pen0.1_lr1e-3 --set action_penalty=0.1 --set learning_rate=1e-3 "${MIXED[@]}"
      ;;
    cpu-tune6)
      # Around cpu-tune5's best (penalty 0.1, mixed noise, learning rate 1e-3): four new seeds;
      # penalty 1; replay ratio 2 (cheaper per env step on the CPU); constant noise; learning
      # rate 2e-3. 4 seeds each (one program), until 2,000 or 5M env steps, six at once.
      export XLA_PYTHON_CLIENT_MEM_FRACTION=0.15
      T=(benchmarks/time_to_score.py Hopper --kind cpu "${OLD_HOPPER_CPU[@]}"
         --cpu-devices 1 --at-once
         --minutes "${TUNE_MINUTES:-7}" --env-steps 5000000 --set learning_rate=1e-3)
      tune cpu_r4_mixed_pen0.1_lr1e-3_seeds4-7 --seeds 4,5,6,7 --set action_penalty=0.1 "${MIXED[@]}"
      tune cpu_r4_mixed_pen1_lr1e-3 --seeds 0,1,2,3 --set action_penalty=1 "${MIXED[@]}"
      tune cpu_r2_mixed_pen0.1_lr1e-3 --seeds 0,1,2,3 --set action_penalty=0.1 "${MIXED[@]}" \
        --train replay_ratio=2
      tune cpu_r2_mixed_pen1_lr1e-3 --seeds 0,1,2,3 --set action_penalty=1 "${MIXED[@]}" \
        --train replay_ratio=2
      tune cpu_r4_pen0.1_lr1e-3 --seeds 0,1,2,3 --set action_penalty=0.1
      tune cpu_r4_mixed_pen0.1_lr2e-3 --seeds 0,1,2,3 --set action_penalty=0.1 "${MIXED[@]}" \
        --set learning_rate=2e-3
      ;;
    cpu-tune7)
      # Around cpu-tune6's best (penalty 0.1, mixed noise, learning rate 2e-3: 1.54M env steps
      # to 2,000 on average; on the 2-core CPU 4 seeds of 5 within 5 minutes, seed 3 stuck near
      # 300 to 700): eight new seeds of it; and eight seeds each of one std (0.3), penalty 1,
      # learning rate 3e-3. Each one program, until 2,000 or 5M env steps, four at once.
      export XLA_PYTHON_CLIENT_MEM_FRACTION=0.2
      T=(benchmarks/time_to_score.py Hopper --kind cpu --cpu-devices 1 --at-once
         --minutes "${TUNE_MINUTES:-7}" --env-steps 5000000)
      S=(--seeds 0,1,2,3,4,5,6,7)
      tune cpu_preset_seeds8-15 --seeds 8,9,10,11,12,13,14,15
      tune cpu_preset_sigma0.3 "${S[@]}" --set sigma=0.3 --set sigma_min=None
      tune cpu_preset_pen1 "${S[@]}" --set action_penalty=1
      tune cpu_preset_lr3e-3 "${S[@]}" --set learning_rate=3e-3
      ;;
    cheetah-explore)
      # HalfCheetah's seed 2, which stood still (about 1,000) for all of its 17.5M env steps
      # with the shared gpu preset's stds (0.05 to 0.4), with wider exploration: stds 0.05 to
      # 0.8, and 0.2 to 0.6 (what its preset now has). Two runs sharing the GPU, 8.3 min each,
      # stopping at 3,000.
      export XLA_PYTHON_CLIENT_MEM_FRACTION=0.45
      T=(benchmarks/time_to_score.py HalfCheetah --kind gpu --cpu-devices 1 --seeds 2
         --minutes 8.3)
      tune cheetah_seed2_sigma0.8 --set sigma=0.8 --set sigma_min=0.05
      tune cheetah_seed2_sigma0.2to0.6 --set sigma=0.6 --set sigma_min=0.2
      ;;
    hopper-seeds)
      # Hopper's five seeds with its gpu preset as it was (no action penalty), and with
      # HalfCheetah's wider noise (stds 0.2 to
      # 0.6), each five seeds in one program (--at-once), the two sharing the GPU, until 2,500 or
      # 6M env steps: the env steps each seed needs, which the 90 s target caps at about 6M
      # (60 s at 98k env steps/s after 30 s of start). Seed 3 peaked at 1,800 in 5.84M alone.
      export XLA_PYTHON_CLIENT_MEM_FRACTION=0.45
      T=(benchmarks/time_to_score.py Hopper --kind gpu --set action_penalty=0 --cpu-devices 1
         --seeds 0,1,2,3,4 --at-once
         --minutes 8.6 --env-steps 6000000)
      tune hopper_seeds_preset
      tune hopper_seeds_sigma0.2to0.6 --set sigma=0.6 --set sigma_min=0.2
      ;;
    hopper-pen)
      # hopper-seeds with a penalty on the pre-tanh actions of 0.1 and of 1: two seeds of five
      # there (0 and 3) had their policy pinned at the tanh's limits (gradient norm about 1e-4)
      # for 300k to 700k env steps.
      export XLA_PYTHON_CLIENT_MEM_FRACTION=0.45
      T=(benchmarks/time_to_score.py Hopper --kind gpu --cpu-devices 1 --seeds 0,1,2,3,4 --at-once
         --minutes "${TUNE_MINUTES:-8.6}" --env-steps 6000000)
      tune hopper_seeds_pen0.1 --set action_penalty=0.1
      tune hopper_seeds_pen1 --set action_penalty=1
      ;;
    hopper-lr)
      # hopper-pen's penalty of 0.1 (the gpu preset now) at learning rates 1e-3 and 2e-3
      # instead of 3e-4: on the cpu layout, with the penalty, 2e-3 needed 0.6x the env steps.
      export XLA_PYTHON_CLIENT_MEM_FRACTION=0.45
      T=(benchmarks/time_to_score.py Hopper --kind gpu --cpu-devices 1 --seeds 0,1,2,3,4 --at-once
         --minutes "${TUNE_MINUTES:-8.6}" --env-steps 6000000)
      tune hopper_seeds_lr1e-3 --set learning_rate=1e-3
      tune hopper_seeds_lr2e-3 --set learning_rate=2e-3
      ;;
    hopper-bf16)
      # hopper-lr's 1e-3 with the networks computing in bfloat16 (seeds 0-4, against hopper-lr's
      # float32 run of the same seeds), and in float32 on five more seeds (5-9).
      export XLA_PYTHON_CLIENT_MEM_FRACTION=0.45
      T=(benchmarks/time_to_score.py Hopper --kind gpu --cpu-devices 1 --at-once
         --minutes "${TUNE_MINUTES:-8.6}" --env-steps 6000000 --set learning_rate=1e-3)
      tune hopper_seeds_lr1e-3_bf16 --seeds 0,1,2,3,4 --set compute_dtype=bfloat16
      tune hopper_seeds_lr1e-3_seeds5-9 --seeds 5,6,7,8,9 --set compute_dtype=float32
      ;;
    bf16-robots)
      # Walker2D's and the Humanoid's gpu presets with their networks in bfloat16, seeds 0-2 in
      # one program each, the two sharing the GPU, until the target or 15M env steps: the env
      # steps each needs, against their float32 runs alone (time_to_score_*_h100*.json).
      T=(benchmarks/time_to_score.py Walker2D --kind gpu --cpu-devices 1 --seeds 0,1,2 --at-once
         --minutes "${TUNE_MINUTES:-8.6}" --env-steps 15000000)
      export XLA_PYTHON_CLIENT_MEM_FRACTION=0.25
      tune walker_seeds_bf16 --set compute_dtype=bfloat16
      T=(benchmarks/time_to_score.py Humanoid --kind gpu --cpu-devices 1 --seeds 0,1,2 --at-once
         --minutes "${TUNE_MINUTES:-8.6}" --env-steps 15000000)
      export XLA_PYTHON_CLIENT_MEM_FRACTION=0.65
      tune humanoid_seeds_bf16 --set compute_dtype=bfloat16
      ;;
    sweep-profile)
      # Where a 16-member sweep's iteration spends the GPU's time, against one member's:
      # sweep-throughput's settings, one chunk traced (benchmarks/research/sweep_profile.py).
      # PROFILE_SET=NAME=VALUE sets a D4PG setting (compute_dtype=bfloat16).
      name=sweep_profile${PROFILE_SET:+_${PROFILE_SET//[=.]/_}}
      XLA_PYTHON_CLIENT_MEM_FRACTION=0.6 timeout 240 python3 benchmarks/research/sweep_profile.py \
        --members "${PROFILE_MEMBERS:-1,16}" --out "$WORK/$name" ${PROFILE_SET:+--set $PROFILE_SET} \
        > "$WORK/$name.txt" 2>&1
      cat "$WORK/$name.txt"
      ;;
    walker-pen)
      # Does the action penalty help another robot? Walker2D's gpu preset, seeds 0-2 in one
      # program, without and with a penalty of 0.1, the two sharing the GPU, until 2,500 or
      # 10M env steps: the env steps to 2,500, or the returns at equal env steps.
      export XLA_PYTHON_CLIENT_MEM_FRACTION=0.45
      T=(benchmarks/time_to_score.py Walker2D --kind gpu --cpu-devices 1 --seeds 0,1,2 --at-once
         --minutes "${TUNE_MINUTES:-8.6}" --env-steps 10000000)
      tune walker_seeds_pen0 --set action_penalty=0
      tune walker_seeds_pen0.1 --set action_penalty=0.1
      ;;
    cheetah-cpu-explore)
      # HalfCheetah's cpu preset (one std, 0.3), which stood still (about 1,000) for its first
      # 15 emulated CPU-minutes (cpu60-HalfCheetah), against mixed noise with stds 0.2 to 0.6
      # (its gpu preset's) and 0.05 to 0.4, seed 0, three sharing the GPU, until 3,000 or the
      # env steps of 60 CPU-minutes: which the hour on the 2-core CPU should run.
      export XLA_PYTHON_CLIENT_MEM_FRACTION=0.3
      T=(benchmarks/time_to_score.py HalfCheetah --kind cpu --cpu-devices 1 --seeds 0
         --minutes 8.6 --env-steps 30800000)
      tune cheetah_cpu_sigma0.3
      tune cheetah_cpu_sigma0.2to0.6 --set sigma=0.6 --set sigma_min=0.2
      tune cheetah_cpu_sigma0.05to0.4 --set sigma=0.4 --set sigma_min=0.05
      ;;
    member-layout)
      # A sweep's envs stepped nested under a member vmap (the trainer's way) or as one flat
      # batch, the physics alone on the GPU.
      XLA_PYTHON_CLIENT_MEM_FRACTION=0.9 timeout 150 python3 \
        benchmarks/research/member_step_layout.py --members "${LAYOUT_MEMBERS:-16,4,1}" --envs 512 \
        > "$WORK/member_layout.txt" 2>&1
      cat "$WORK/member_layout.txt"
      ;;
    cpu60-*)
      # ROBOT's cpu preset for as many env steps as the 2-core CPU steps in 60 minutes less its
      # compile, at its measured rate (BENCHMARKS.md, "On the 2-core CPU": Walker2D 9,000/s,
      # HalfCheetah 8,700, Ant 6,900, Humanoid 5,600), run on past the target; in the
      # background, sharing the GPU with the call's other cpu60 phases. Stopped at
      # $CPU60_MINUTES (8.8) if the GPU is slower than that: its summary then says how many
      # env steps it reached.
      robot=${phase#cpu60-}
      case $robot in
        Walker2D) steps=31900000;; HalfCheetah) steps=30800000;; Ant) steps=24500000;;
        Humanoid) steps=19700000;; *) echo "cpu60: no CPU rate for $robot" >&2; exit 2;;
      esac
      n=$(printf '%s\n' "$@" | grep -c '^cpu60-')
      XLA_PYTHON_CLIENT_MEM_FRACTION=$(python3 -c "print(round(0.9 / $n, 3))") timeout 560 \
        python3 benchmarks/time_to_score.py "$robot" --kind cpu --cpu-devices 1 --seeds 0 \
        --run-on --minutes "${CPU60_MINUTES:-8.8}" --env-steps "$steps" \
        --label "60 CPU-minutes, emulated" \
        --out "$WORK/cpu60_$robot" > "$WORK/cpu60_$robot.txt" 2>&1 &
      ;;
    collect-parts)
      # What a 16-member sweep's collection spends its time on (physics, policy, replay
      # write), alone on the GPU (benchmarks/research/sweep_collect_parts.py).
      XLA_PYTHON_CLIENT_MEM_FRACTION=0.9 timeout 160 python3 \
        benchmarks/research/sweep_collect_parts.py --members "${PARTS_MEMBERS:-16,1}" \
        > "$WORK/collect_parts.txt" 2>&1
      cat "$WORK/collect_parts.txt"
      ;;
    compile-parts)
      # Where the gpu preset's first minute goes (imports, init, tracing and compiling the
      # chunk and the evaluation), alone on the GPU, each XLA_FLAGS variant in a fresh process
      # (benchmarks/research/compile_parts.py): mjx_hopper's default (cuBLAS for the
      # products) against XLA's (Triton's GEMM fusions). As run first on 2026-11-24, before
      # mjx_hopper turned Triton's off, COMPILE_VARIANTS was ";--xla_gpu_enable_triton_gemm=false;
      # --xla_gpu_enable_triton_gemm=false --xla_gpu_autotune_level=0;
      # --xla_gpu_force_compilation_parallelism=8" (as one line).
      XLA_PYTHON_CLIENT_MEM_FRACTION=0.9 timeout 360 python3 benchmarks/research/compile_parts.py \
        --env "${PARTS_ENV:-Hopper}" --kind gpu --out "$WORK/compile_parts_${PARTS_ENV:-Hopper}.json" \
        --variants "${COMPILE_VARIANTS:-;--xla_gpu_enable_triton_gemm=true}" \
        > "$WORK/compile_parts.txt" 2>&1
      cat "$WORK/compile_parts.txt"
      ;;
    sweep-precision)
      # sweep-throughput's 16-member sweep with XLA's default float32 products (TF32 on an
      # H100) and with bfloat16 inputs accumulated in float32 (JAX_DEFAULT_MATMUL_PRECISION's
      # dot algorithm BF16_BF16_F32; its "bfloat16" level is XLA's default), alone on the GPU.
      # As run on 2026-11-24 both had XLA's Triton GEMM fusions (mjx_hopper turned them off
      # after); XLA_FLAGS=--xla_gpu_enable_triton_gemm=true reruns it so.
      for precision in default BF16_BF16_F32; do
        env $([ $precision = default ] || echo JAX_DEFAULT_MATMUL_PRECISION=$precision) \
          XLA_PYTHON_CLIENT_MEM_FRACTION=0.9 timeout 150 python3 benchmarks/sweep_throughput.py \
          --preset gpu --num-envs 512 --batch-size 1024 --replay-size 1000000 --chunk 10 \
          --chunks 3 --members "${PRECISION_MEMBERS:-16}" --cpu-devices 1 \
          --out "$WORK/sweep_precision_$precision.json" > "$WORK/sweep_precision_$precision.txt" 2>&1
        tail -5 "$WORK/sweep_precision_$precision.txt"
      done
      ;;
    sweep-triton)
      # sweep-throughput's 1- and 16-member sweeps with mjx_hopper's cuBLAS products and with
      # XLA's Triton GEMM fusions, alone on the GPU (as first run, the Triton one had only 16).
      for variant in cublas triton; do
        members=${TRITON_MEMBERS:-1,16}
        env $([ $variant = cublas ] || echo XLA_FLAGS=--xla_gpu_enable_triton_gemm=true) \
          XLA_PYTHON_CLIENT_MEM_FRACTION=0.9 timeout 200 python3 benchmarks/sweep_throughput.py \
          --preset gpu --num-envs 512 --batch-size 1024 --replay-size 1000000 --chunk 10 \
          --chunks 3 --members $members --cpu-devices 1 \
          --out "$WORK/sweep_$variant.json" > "$WORK/sweep_$variant.txt" 2>&1
        tail -6 "$WORK/sweep_$variant.txt"
      done
      ;;
    humanoid-ls)
      # Fewer line-search steps (under vmap MJX's line search runs all of its steps): four
      # variants through the stability check.
      for v in "all 4/4" "all 4/2" "all 3/3" "legs 3/3"; do stable "$BEFORE_ARMATURE $v"; done
      ;;
    *) echo "unknown phase $phase; phases: install-and-tune, d4pg, ddpg, mpo, dmpo, cpu-tune, mpo-tune, mpo-cpu-seed2, mpo-acme-std, humanoid-stability, humanoid-ls, humanoid-shipped, humanoid-before, humanoid-capture, humanoid-limits, humanoid-armature, humanoid-confirm, mpo-pairN, sweep-throughput, peers, scaling, scaling-rest, sweep-collect, screen-hopper, screen-humanoid, humanoid-solve, tts-ROBOT, hopper-cold, cold-ROBOT, cpu-tune2, cpu-tune3, cpu-tune4, projection-cost, cpu-tune5, cpu-tune6, cpu-tune7, member-layout, collect-parts, cpu60-ROBOT, compile-parts, sweep-precision, sweep-triton, cheetah-explore, hopper-seeds, cheetah-cpu-explore, hopper-pen, walker-pen, hopper-lr, hopper-bf16, bf16-robots, sweep-profile, wait" >&2
       exit 2 ;;
  esac
done
wait
for f in "$WORK"/*.txt; do echo "== $f"; tail -6 "$f"; done
tar czf "$OUT/results.tgz" --exclude checkpoints -C "$WORK" .
