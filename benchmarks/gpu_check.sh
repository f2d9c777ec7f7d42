#!/usr/bin/env bash
# The GPU checks: the CUDA tests, then the estimation and throughput benchmarks with torch_dq
# on the GPU beside its CPU and GTSAM on the same machine. Each step has its own time limit
# and log under OUT_DIR; run from the repository's root, naming the steps (default: all):
#
#     bash benchmarks/gpu_check.sh OUT_DIR [tests] [gtsam] [ops] [hour]
set -u
out=$1
shift
steps=${*:-tests gtsam ops hour}
mkdir -p "$out"
export PYTHONUNBUFFERED=1
py=${PYTHON:-python3}
step() {  # step NAME SECONDS COMMAND...: one timed step, its output in OUT_DIR/NAME.log
    local name=$1 limit=$2
    shift 2
    echo "== $name ($(date -u +%H:%M:%S))"
    timeout "$limit" "$@" >"$out/$name.log" 2>&1
    echo "   exit $? after $SECONDS s in all"
    tail -n 30 "$out/$name.log"
}
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader
$py -c "import torch; print('torch', torch.__version__, torch.cuda.get_device_name())"
for s in $steps; do
    case $s in
    tests) step cuda_tests 170 $py -m pytest -q -n 8 -p no:cacheprovider -k cuda tests/ ;;
    gtsam)
        step gtsam_60s 100 $py benchmarks/bench_gtsam.py --repeats 3 --threads 1 --device cuda
        step gtsam_60s_cpu 60 $py benchmarks/bench_gtsam.py --repeats 3 --threads 1 \
            --only torch_dq ;;
    ops) step ops_quick 90 $py benchmarks/run.py --quick --device cuda --no-compile ;;
    hour) step hour 200 $py benchmarks/bench_gtsam.py --scaling --durations 600,3600 \
        --threads 1 --only torch_dq --device cuda ;;
    esac
done
