#!/usr/bin/env bash
# One optuna study shared by two rl-zoo3 workers through PostgreSQL, for real.
#
# Starts a throwaway PostgreSQL server from Debian's package (apt-get install postgresql) on a free local port,
# creates the study, runs the README's "several machines" command twice at once (two workers, here two processes on one machine; on several
# machines the storage URL names the server's host instead of 127.0.0.1), then checks with optuna that the study
# holds every trial of both workers. Needs the `postgres` extra (pip install -e ".[postgres]": psycopg 3, the
# driver SQLAlchemy 2.1 uses for postgresql://).
#
#   benchmarks/optuna_postgres.sh 2>&1 | tee benchmarks/results/optuna_postgres.log
#
# Tiny settings (300 steps per trial, tiny networks) keep it to a few minutes on 2 cores; set N_TRIALS / STEPS for more.
set -euo pipefail
cd "$(dirname "$0")/.."
N_TRIALS=${N_TRIALS:-2}   # per worker
STEPS=${STEPS:-300}
PG_BIN=${PG_BIN:-$(find /usr/lib/postgresql -maxdepth 2 -name bin -type d | sort -V | tail -1)}
[ -x "$PG_BIN/initdb" ] || { echo "no PostgreSQL server found (apt-get install postgresql, or set PG_BIN)" >&2; exit 1; }

WORK=$(mktemp -d)
# PostgreSQL refuses to run as root: as root, run the server as Debian's `postgres` user
if [ "$(id -u)" = 0 ]; then
  chown postgres "$WORK"
  as_server() { runuser -u postgres -- "$@"; }
else
  as_server() { "$@"; }
fi
PORT=$(python -c "import socket; s = socket.socket(); s.bind(('127.0.0.1', 0)); print(s.getsockname()[1])")
cleanup() {
  as_server "$PG_BIN/pg_ctl" -D "$WORK/data" -m fast stop > /dev/null 2>&1 || true
  rm -rf "$WORK"
}
trap cleanup EXIT

echo "== PostgreSQL $("$PG_BIN/postgres" --version | grep -o "[0-9][0-9.]*" | head -1) on 127.0.0.1:$PORT"
as_server "$PG_BIN/initdb" -D "$WORK/data" -U optuna --auth=trust > /dev/null
as_server "$PG_BIN/pg_ctl" -D "$WORK/data" -l "$WORK/data/server.log" -w \
  -o "-p $PORT -k $WORK -c listen_addresses=127.0.0.1" start > /dev/null
as_server "$PG_BIN/createdb" -h 127.0.0.1 -p "$PORT" -U optuna optuna
STORAGE="postgresql://optuna@127.0.0.1:$PORT/optuna"
STUDY=pebble-walker

# the README recipe, run by each worker (tiny settings on top)
worker() {
  python -m sb3_pride.zoo train --algo pebble --env sb3_pride/walker-walk-v0 -conf hyperparams/cpu/pebble.yml \
    -optimize --n-trials "$N_TRIALS" --n-jobs 1 --storage "$STORAGE" --study-name "$STUDY" \
    -n "$STEPS" -f "$WORK/logs-$1" --sampler random --pruner none --n-evaluations 1 --eval-episodes 1 \
    -params learning_starts:100 unsupervised_steps:100 feedback_interval:100 queries_per_session:10 max_feedback:30 \
    segment_length:20 batch_size:64 buffer_size:5000 "policy_kwargs:dict(net_arch=[32,32])"
}
# the study is created once, before the workers: two rl-zoo3 workers that start at once on an empty database race
# to create optuna's tables and one dies ("duplicate key value violates unique constraint", seen here); optuna's
# CLI creates it as rl-zoo3 would (maximize), and each worker then loads it (rl-zoo3 passes load_if_exists=True)
optuna create-study --storage "$STORAGE" --study-name "$STUDY" --direction maximize
echo "== two workers, $N_TRIALS trials each, one study ($STUDY) at $STORAGE"
START=$(date +%s)
worker 1 > "$WORK/worker-1.log" 2>&1 &
W1=$!
worker 2 > "$WORK/worker-2.log" 2>&1 &
W2=$!
status=0
wait $W1 || status=$?
wait $W2 || status=$?
for w in 1 2; do
  echo "-- worker $w (last lines of its log)"
  grep -E "Trial [0-9]+ (finished|failed|pruned)" "$WORK/worker-$w.log" || tail -20 "$WORK/worker-$w.log"
done
[ "$status" = 0 ] || { echo "a worker failed (exit $status)"; exit "$status"; }
echo "== both workers done in $(( $(date +%s) - START )) s; the study, read back with optuna:"

WORK=$WORK STORAGE=$STORAGE STUDY=$STUDY N_TRIALS=$N_TRIALS python - <<'PY'
import os
import re

import optuna

study = optuna.load_study(study_name=os.environ["STUDY"], storage=os.environ["STORAGE"])
complete = {t.number for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE}
for trial in study.trials:
    print(f"trial {trial.number}: {trial.state.name}, value {trial.value}, params {trial.params}")
per_worker = {}
for worker in (1, 2):
    with open(os.path.join(os.environ["WORK"], f"worker-{worker}.log")) as log:
        per_worker[worker] = {int(n) for n in re.findall(r"Trial (\d+) finished", log.read())}
    print(f"worker {worker} finished trials {sorted(per_worker[worker])}")
n_trials = int(os.environ["N_TRIALS"])
assert all(len(trials) == n_trials for trials in per_worker.values()), per_worker
assert per_worker[1].isdisjoint(per_worker[2]), "both workers ran the same trial"
assert per_worker[1] | per_worker[2] == complete, (per_worker, complete)
print(f"OK: the study holds all {len(complete)} trials, {n_trials} from each worker; best {study.best_value} with {study.best_params}")
PY
