"""Which kind of pursuit-mj YAML file a mapping is (layout, task, train config, flight file), so
that a file given where another kind goes is refused saying what it is and where it belongs,
not as 'unknown key arena (did you mean run?)'."""

from __future__ import annotations

from typing import Any

from .configio import ConfigError

#: per kind: top-level keys that only that kind of file has, what it is, and where it goes
KINDS: dict[str, tuple[tuple[str, ...], str, str]] = {
    "layout": (("arena", "boundary", "spawn"), "a layout file",
               "give it with -i/--layout FILE, or among --layouts for a table (eval, demo, study), or as layout: FILE "
               "in a task or flight file"),
    "train": (("ppo", "regime", "algo", "n_envs", "total_steps", "task_file"), "a train config",
              "give it to pursuit-mj train --config FILE"),
    "flight": (("drones", "positioning", "transform", "lab", "safety", "decision_rate", "max_time"), "a flight file",
               "give it to pursuit-mj fly --flight FILE"),
    "task": (("n_pursuers", "n_evaders", "pursuer_speed", "evader_speed", "perception_radius", "field_of_view",
              "capture_radius", "observability", "fidelity", "control_dt", "max_steps", "evader", "random_layout"),
             "a task file", "give it with --task FILE (in train: --set task_file=FILE, or its keys under task:)"),
}


def refuse_another_kind(data: Any, source: str, expected: str) -> None:
    """ConfigError naming `source` when the mapping `data`, read as a file of kind `expected` (a
    key of KINDS), has keys that only another kind has; nothing for a mapping of no other kind's
    keys (its own loader names what is wrong with it) or for anything but a mapping."""
    if not isinstance(data, dict):
        return
    for kind, (keys, what, where) in KINDS.items():
        found = [k for k in keys if k in data]
        if kind != expected and found and not any(k in data for k in KINDS[expected][0]):
            raise ConfigError(f"{source}: this is {what} (it has {', '.join(found)}), not {KINDS[expected][1]}: {where}")
