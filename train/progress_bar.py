"""The training run's progress bar: percent of the run, with live success, collisions and throughput,
labelled by the run's name and the fidelity it trains in."""

from __future__ import annotations

from .config import TrainConfig
from .validation import summarise


# how the bar's label names the fidelity (short: the label leads the line)
FIDELITY_SHORT = {"point": "point", "quadrotor": "quad"}


def progress_bar(cfg: TrainConfig, done: float):
    """A tqdm bar in percent of the run (by steps, or by time when max_minutes ends it sooner),
    labelled 'NAME (FIDELITY)', e.g. 'classic (quad)', so that two runs side by side tell apart."""
    if not cfg.run.progress:
        return None
    from tqdm import tqdm

    label = f"{cfg.name} ({FIDELITY_SHORT.get(cfg.task.fidelity, cfg.task.fidelity)})"
    return tqdm(total=100.0, initial=round(100.0 * done, 1), unit="%", desc=label, dynamic_ncols=True,
                smoothing=0.1, bar_format="{desc}: {percentage:3.0f}%|{bar}| [{elapsed}<{remaining}{postfix}]")


def advance_bar(bar, row: dict, recent, last_val: dict, done: float, note: str = "") -> None:
    """Move the bar to `done` (fraction of the run) with live training figures; `note` says what runs now."""
    if bar is None:
        return
    s = summarise(list(recent)) if recent else {}
    post = {
        "steps": row["world_steps"],  # "-" below: no episode has ended yet
        "succ": f"{s['success']:.0%}" if s else "-", "coll": f"{s['collision']:.0%}" if s else "-",
        "ep_len": f"{s['mean_steps']:.0f}" if s else "-",
        "agent_sps": f"{row['agent_steps_per_s']:.0f}",  # pursuer transitions, not the world steps of `steps`
    }
    if "gamma_meta_grad" in row:
        post["gamma"] = f"{row['gamma']:.4f}"
    if last_val:
        post["val"] = f"{last_val['success']:.0%}"
        if "vs_heuristic_steps" in last_val:
            post["val_vs_heur"] = f"{last_val['vs_heuristic_steps']:+.0f} steps"
    if note:
        post["now"] = note
    bar.set_postfix(post, refresh=False)
    bar.update(max(round(100.0 * done, 1) - bar.n, 0.0))
    if note:
        bar.refresh()  # the update may not redraw (tqdm's miniters), and what follows can take a while
