#!/usr/bin/env bash
# The reference-preset recipe at fixed step counts, one stage after another (docs/training.md,
# "What training reaches"):
#   1. NAME_bel    DAgger from the heuristic team, with belief features, point fidelity
#   2. NAME_ppo    PPO from NAME_bel's best checkpoint, point fidelity
#   3. NAME_quad   PPO from NAME_ppo's best checkpoint, quadrotor fidelity
#   4. NAME_kick   PPO from NAME_quad's best checkpoint with the team as a teacher from step 200
#                  of each episode on; its last.pt is the result
# --seed sets the seed of stages 1 and 2; stages 3 and 4 keep the seeds of the runs behind
# pretrained/belppo_kick.pt (0 and 3). The run folders go into --runs-dir (default: the
# repository's runs/; a relative DIR is taken from the current folder). A stage whose run
# folder already has a last.pt is resumed (a finished one returns at once), so after Ctrl-C
# or a crash the same command continues where it stopped. Every stage runs one torch thread
# per process (`--set run.torch_threads=1`), so the weights do not depend on the core count.
# Flags after the options (e.g. `--set run.torch_threads=0` to use more threads, which changes
# the weights in their last bits) go to every stage's `pursuit-mj train`. PURSUIT_MJ names
# the command to run instead of the one scripts/setup.sh installs into .venv.
# Usage: bash scripts/train_recipe.sh [--seed S] [--name NAME] [--runs-dir DIR] [train flags...]
# (the three options first: a seed or --runs-dir among the train flags is refused)
set -euo pipefail
seed=1
name=recipe
runs_dir=
while [ $# -gt 0 ]; do
  case "$1" in
    --seed|--name|--runs-dir)
      [ $# -ge 2 ] || { echo "train_recipe.sh: $1 needs a value" >&2; exit 2; }
      case "$1" in --seed) seed=$2 ;; --name) name=$2 ;; --runs-dir) runs_dir=$2 ;; esac
      shift 2 ;;
    *) break ;;
  esac
done
case "$runs_dir" in
  '') runs_dir=runs ;;  # the repository's runs/, as in the docs
  /*) ;;
  *) runs_dir="$(pwd)/$runs_dir" ;;  # a relative --runs-dir is taken from where the command was run
esac
case "${PURSUIT_MJ:-}" in
  */*) [ "${PURSUIT_MJ#/}" != "$PURSUIT_MJ" ] || PURSUIT_MJ="$(pwd)/$PURSUIT_MJ" ;;  # a relative path, before the cd
esac
cd "$(dirname "$0")/.."
case "$seed" in
  ''|*[!0-9]*) echo "train_recipe.sh: --seed must be a non-negative integer, got '$seed'" >&2; exit 2 ;;
esac
for arg in "$@"; do
  case "$arg" in
    run.runs_dir=*|--name|--name=*|--resume|--resume=*|--init-from|--init-from=*)
      echo "train_recipe.sh: $arg is set by the recipe itself (use --runs-dir DIR, --name NAME)" >&2; exit 2 ;;
    # each stage sets its own seed (--set seed=, which wins over a flag), so a seed among the train flags
    # would reach only the stage that sets none, silently giving a chain of mixed seeds
    --seed|--seed=*|seed=*|--set=seed=*)
      echo "train_recipe.sh: $arg among the train flags would reach only some stages (the recipe sets each" \
        "stage's seed); give --seed S first, before any train flag" >&2; exit 2 ;;
    --runs-dir|--runs-dir=*)
      echo "train_recipe.sh: $arg comes before the train flags (the options are read up to the first" \
        "train flag): --seed S --name NAME --runs-dir DIR [train flags]" >&2; exit 2 ;;
  esac
done
if [ -z "${PURSUIT_MJ:-}" ]; then
  bash scripts/setup.sh
  PURSUIT_MJ=.venv/bin/pursuit-mj
fi
export MUJOCO_GL=${MUJOCO_GL:-egl}

# stage NAME ARGS...: train run NAME (resumed if it has a last.pt) with the recipe's flags, then the extra ones
stage() {
  local run=$1
  shift
  local resume=()
  [ -f "$runs_dir/$run/last.pt" ] && resume=(--resume)
  echo "== train_recipe.sh: $run" >&2
  # one torch thread per process: more threads round the update differently, so without this
  # a machine with 4+ cores would train other weights than the documented chains (2 cores split
  # the update into two processes of one thread each anyway)
  "$PURSUIT_MJ" train --name "$run" --set run.runs_dir="$runs_dir" --set run.torch_threads=1 "$@" \
    ${resume[@]+"${resume[@]}"}
}

stage "${name}_bel" --config belief --set task.fidelity=point --set seed="$seed" --set total_steps=193536 "$@"
stage "${name}_ppo" --config belief_ppo --set task.fidelity=point --set seed="$seed" --set total_steps=425984 \
  --init-from "$runs_dir/${name}_bel/best.pt" "$@"
stage "${name}_quad" --config belief_ppo --set total_steps=204800 --init-from "$runs_dir/${name}_ppo/best.pt" "$@"
stage "${name}_kick" --config belief_ppo --set seed=3 --set ppo.critic_warmup=48 --set ppo.teacher_coef=2 \
  --set ppo.teacher_from_step=200 --set total_steps=303104 --init-from "$runs_dir/${name}_quad/best.pt" "$@"
echo "== train_recipe.sh: done; the policy is $runs_dir/${name}_kick/last.pt" >&2
