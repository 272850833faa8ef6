"""`pursuit-mj render`: episodes as mp4/gif, final-state PNGs and rerun recordings.

    pursuit-mj render --policy heuristic -i 2 --episodes 3 -s renders/
    pursuit-mj render -m runs/classic/best.pt -s chase.gif --camera follow:pursuer_0
    pursuit-mj render -mc classic -i 1 --final-frame --no-video --episodes 50 -s finals/
    pursuit-mj render --policy heuristic --rerun chase.rrd --no-video

The short flags of the reference study's run_sim.py work (-mc, -ec, -m, -s, -sc, -i, -rv,
-ev, --delta_t, --r_perception, --obstacle_num), with speeds and radii in m and m/s.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import re
import sys
from pathlib import Path

from pursuit_mj.io_utils import check_writable_folder, no_new_empty_folders
from pursuit_mj.config import TaskConfig, load_task_yaml, preset_or_file
from pursuit_mj.configio import dump_yaml, load, to_dict
from pursuit_mj.layout import N_BUILTIN, load_layout
from pursuit_mj.obs_spec import ObsSpec
from pursuit_mj.policies import POLICY_NAMES, make_policy
from pursuit_mj.evader_models import evader_model_sha256
from pursuit_mj.policy_file import is_policy_file, policy_file_name, policy_file_path
from .common import (add_shield_arg, add_task_args, check_episodes, check_evader_model, check_layout_given, flags_typed, load_model, path_arg, seed_arg, sweep_dead_parts,
                     finite_float, once_flag, shield_each_if_asked, task_config_from_args, task_flag_error, task_flags_given,
                     task_named)

DEFAULT_SAVE = "renders"


def register(sub) -> None:
    p = sub.add_parser(
        "render",
        help="render episodes to mp4/gif, final-state PNGs and rerun recordings",
        description="Play episodes of a policy and write what happened: videos (mp4 or gif, by file name or "
                    "--format), the last frame of each episode as PNG (--final-frame), and a rerun recording "
                    "(--rerun FILE.rrd). Rendering is offscreen (EGL or OSMesa, chosen automatically).",
    )
    who = p.add_argument_group("policy")
    ex = who.add_mutually_exclusive_group()
    once = once_flag("render plays one policy (eval takes several, a row each)")
    ex.add_argument("-m", "--model", metavar="FILE", action=once, help="trained checkpoint (default: best.pt of the -mc run, else --policy)")
    ex.add_argument("--policy", type=policy_arg, action=once, metavar="NAME|FILE.py:NAME",
                    help=f"a hand-made team ({', '.join(POLICY_NAMES)}; default heuristic), or a policy of your own: "
                         "NAME(config, seed) from a Python file (docs/env_api.md, 'Policies')")
    who.add_argument("-mc", "--model-config", metavar="FILE|PRESET",
                     help="training config (file or preset, e.g. classic): its task is the base task and its run's best.pt the default model")
    add_shield_arg(who)
    out = p.add_argument_group("output")
    out.add_argument("-s", "--save-path", type=path_arg, default=DEFAULT_SAVE, metavar="DIR|FILE",
                     help=f"folder for videos and images, or a video file name (.mp4/.gif); a name ending in / is a folder "
                          f"(default {DEFAULT_SAVE}/). Files in a folder are named <policy>[_<task>]_layout<L>_<fidelity>_seed<S>_<digest>_ep<k> "
                          f"(<task>: each --task given), the digest changing with anything else they show, so a render never overwrites another's")
    out.add_argument("--format", choices=("mp4", "gif"), help="video format when -s is a folder (default mp4)")
    out.add_argument("--final-frame", action="store_true", help="also save the last frame of each episode as PNG")
    out.add_argument("--no-video", action="store_true", help="write no video (with --final-frame and/or --rerun)")
    out.add_argument("--rerun", type=path_arg, metavar="FILE.rrd", help="record all episodes for the rerun viewer (rerun FILE.rrd)")
    run_g = p.add_argument_group("episodes and frames")
    run_g.add_argument("--episodes", type=int, help="episodes to play (default 1)")
    run_g.add_argument("--seed", type=seed_arg, default=0, help="table seed: plays the episodes eval --seed plays on the layout (default 0)")
    run_g.add_argument("--episode-seed", type=seed_arg, action="append", metavar="N", dest="episode_seeds",
                       help="play the episode of this episode seed instead (repeatable); eval's JSON lists each "
                            "episode's seed (rows[].per_episode.seed), so an episode of an evaluation table replays "
                            "here with the same task flags; files are named ..._episode<N>")
    run_g.add_argument("--width", type=int, default=640, help="frame width in pixels (default 640)")
    run_g.add_argument("--height", type=int, default=480, help="frame height in pixels (default 480)")
    run_g.add_argument("--fps", type=finite_float, help="video frames per second, 0.01 to 1e6 (default: real time, 1/control_dt; a GIF plays at most 50, so with gif a control_dt below 0.02 s needs --fps)")
    run_g.add_argument("--camera", default="top", help="top, angled, or follow:<drone> e.g. follow:pursuer_0 (default top)")
    run_g.add_argument("--quality", choices=("fast", "high"), default="fast",
                       help="fast: no antialiasing or shadows; high: 4x antialiasing, shadows (slower)")
    run_g.add_argument("--trail", type=int, default=30, help="trail length in decision steps (default 30)")
    run_g.add_argument("--no-key", action="store_true", help="leave the colour key off the bottom of each frame")
    add_task_args(p)
    _add_reference_spellings(p)
    p.set_defaults(func=run)


def _add_reference_spellings(p: argparse.ArgumentParser) -> None:
    """The reference study's underscore spellings, accepted but not listed in --help."""
    hidden = argparse.SUPPRESS
    p.add_argument("--model_config", dest="model_config", help=hidden)
    p.add_argument("--save_path", dest="save_path", help=hidden)  # the task ones: common.add_task_args


# ---------------------------------------------------------------------- config and policy


def _train_config(ref: str, args):
    """The -mc run's train config; the task keys that render's -ec files, own flags and --set replace
    are not looked up in it (a layout or evader file of the run that is gone is no error when replaced)."""
    try:
        from train.config import load_train_config
    except ImportError as exc:
        raise ValueError(f"-mc {ref}: cannot read training configs, the train package is not importable ({exc})") from None
    return load_train_config([ref], replaced=_task_keys_given(args))


def _task_keys_given(args) -> set[str]:
    """The task keys ('task.layout' ...) that render's -ec files, -i and --set give, over the -mc run's."""
    from train.config import dotted_keys, set_keys

    given = set()
    for f in args.task_files:  # read again by task_config, which applies them
        given |= dotted_keys(load_task_yaml(preset_or_file(f, "task")), "task.")
    for text in args.overrides:  # one that does not parse: task_config names it
        given |= set_keys(text, "task.")
    if getattr(args, "layout", None) is not None:
        given.add("task.layout")
    return given


def _refuse_a_layout_the_run_never_met(args, train_cfg, config: TaskConfig) -> None:
    """ValueError when the -mc run trained on several layouts (`layouts`: one per world, or drawn per
    episode with random_layout) and no layout is given here: its task's own layout (or, drawn, the
    built-in ones) is not what it trained on, and rendering it would show another arena than the run's."""
    if not train_cfg.layouts or "task.layout" in _task_keys_given(args):
        return
    if not config.random_layout and {str(layout) for layout in train_cfg.layouts} == {str(config.layout)}:
        return  # it trained on its task's layout alone
    met = ", ".join(str(layout) for layout in train_cfg.layouts)
    if config.random_layout:
        raise ValueError(f"-mc {args.model_config}: the run trained on layouts {met}, each episode drawing one of them, "
                         f"where a render draws from the built-in layouts 0-3; render one of the run's with -i LAYOUT "
                         f"--set random_layout=false")
    raise ValueError(f"-mc {args.model_config}: the run trained on layouts {met} (one per world), not on its task's "
                     f"layout {config.layout}; render one of them (or any other) with -i LAYOUT")


def task_config(args, base: TaskConfig | None) -> TaskConfig:
    """defaults <- base (the -mc run's task) <- -ec files <- task flags <- --set, its evader model
    made once (check_evader_model); printed with -sc. As for task_config_from_args, each source's
    values are checked as it is read and the checks across keys judge the whole."""
    if base is None:
        return task_config_from_args(args)
    flags, names = task_flags_given(args)
    typed = flags_typed((names[k], v) for k, v in flags.items()) if flags else "command-line flag"
    files = [preset_or_file(f, "task") for f in args.task_files]
    try:
        cfg = load(TaskConfig, files, args.overrides, extra=flags, extra_source=typed, read=load_task_yaml,
                   base=to_dict(base), base_source=f"-mc {args.model_config}: task")
    except ValueError as exc:
        raise task_flag_error(exc, typed, flags, names) from None
    check_evader_model(cfg, "evader.model")  # as task_config_from_args: one line, before any file or the digest
    check_layout_given(args, cfg)
    if args.show_config:
        print(dump_yaml(cfg))
    return cfg


def layout_tag(config: TaskConfig) -> str:
    """The layout part of file names: its index or file stem, 'random' when each episode draws a built-in one."""
    return "random" if config.random_layout else Path(str(config.layout)).stem


def policy_arg(text: str) -> str:
    """--policy: a hand-made team's name or FILE.py:NAME (argparse names the flag on a mistake)."""
    if text in POLICY_NAMES or is_policy_file(text):
        return text
    raise argparse.ArgumentTypeError(f"expected one of {', '.join(POLICY_NAMES)} or FILE.py:NAME, got {text!r}")


FILE_LABEL_CHARS = 64  # a policy's part of a file name: with a layout name (at most 100 bytes) and the rest, under 255


def file_label(name: str) -> str:
    """A policy's name as it can stand in a file name: characters other than letters, digits,
    '.', '_' and '-' become '_', a leading '.' too (no hidden files); a name longer than
    FILE_LABEL_CHARS is cut, ending in six hex digits of the whole name to keep two such apart."""
    text = re.sub(r"[^A-Za-z0-9._-]", "_", name.strip())
    if text.startswith("."):
        text = "_" + text[1:]
    if len(text) > FILE_LABEL_CHARS:
        text = f"{text[:FILE_LABEL_CHARS - 7]}-{hashlib.sha256(name.encode()).hexdigest()[:6]}"
    return text


def checkpoint_file(args, train_cfg) -> Path | None:
    """The checkpoint choose_policy loads: -m FILE, else the -mc run's best.pt unless --policy; None for a hand-made team."""
    if args.model:
        return Path(args.model)
    if args.policy is None and train_cfg is not None:
        return train_cfg.run_dir / "best.pt"
    if args.policy is not None and is_policy_file(args.policy):
        return policy_file_path(args.policy)  # its code decides the pictures, as a checkpoint's bytes do
    return None


def render_digest(config: TaskConfig, label: str, checkpoint: Path | None, frames: dict, factory: str | None = None,
                  evader_seed: int | None = None) -> str:
    """Six hex digits of everything that decides what a render shows (the seed aside, which the
    name spells out): the task with its layout's content, the policy (a checkpoint by its bytes)
    and the frame settings; for --policy FILE.py:NAME, the file by its bytes and `factory`, NAME
    (two factories of one file may give policies of one name), with --episode-seed followed by
    the --seed that NAME(config, seed) was given; an evader.model FILE.py:NAME by
    its file's bytes, and by `evader_seed` where given (with --episode-seed, the --seed that
    NAME(config, n_worlds, seed) was given). Files named alike hold the same
    pictures, so a render replaces only its own earlier copy, never a render of another model,
    task or camera."""
    h = hashlib.sha256()
    h.update(json.dumps(to_dict(config), sort_keys=True, default=str).encode())
    h.update(repr(load_layout(config.layout)).encode())
    h.update(label.encode())
    if checkpoint is not None:
        h.update(hashlib.sha256(checkpoint.read_bytes()).digest())
    h.update(json.dumps(frames, sort_keys=True).encode())
    if factory is not None:  # nothing added otherwise: the names of earlier renders stay as they were
        h.update(f"factory {factory}".encode())
    evader = evader_model_sha256(config)
    if evader is not None:  # likewise: an evader model of one's own by its bytes
        h.update(f"evader {evader}".encode())
        if evader_seed is not None:
            h.update(f"evader seed {evader_seed}".encode())
    return h.hexdigest()[:6]


def choose_policy(args, config: TaskConfig, train_cfg):
    """(policy, label): -m FILE, else --policy NAME, else the -mc run's best.pt, else heuristic."""
    spec = ObsSpec.make(config.n_pursuers, config.n_evaders, config.n_rays)
    played = list(range(N_BUILTIN)) if config.random_layout else [config.layout]  # a note if the model never met them
    if args.model:
        policy = load_model(args.model, spec, config, layouts=played)
        return policy, getattr(policy, "name", Path(args.model).stem)
    if args.policy:
        policy = make_policy(args.policy, config, args.seed, "--policy")
        return policy, (file_label(policy.name) if is_policy_file(args.policy) else args.policy)
    if train_cfg is not None:
        best = train_cfg.run_dir / "best.pt"
        if not best.is_file():
            raise ValueError(f"-mc {args.model_config}: no checkpoint at {best}; train it first, or pass -m FILE or --policy")
        policy = load_model(best, spec, config, flag=f"-mc {args.model_config}:", layouts=played)
        return policy, getattr(policy, "name", train_cfg.name)
    return make_policy("heuristic", config, args.seed), "heuristic"


# ---------------------------------------------------------------------- output paths


@dataclasses.dataclass(frozen=True)
class SaveTarget:
    """Where -s points: a folder, the file stem when -s names a video file (else None), the video format,
    and the file's extension as the user spelled it (.MP4 stays .MP4)."""

    folder: Path
    file_stem: str | None
    fmt: str
    suffix: str = ""

    def paths(self, episodes: int, stem: str, video: bool, final: bool,
              tags: list[str] | None = None) -> tuple[list[Path] | None, list[Path] | None]:
        """(videos, final PNGs) per episode: `<stem>_<tag>` in a folder; the file name as given for one
        episode, `<name>_<tag>` for several. The tags default to ep<k> (000, 001, ...)."""
        base = self.file_stem or stem
        numbered = self.file_stem is None or episodes > 1
        tags = tags or [f"ep{k:03d}" for k in range(episodes)]
        names = [f"{base}_{tag}" if numbered else base for tag in tags]
        suffix = self.suffix or f".{self.fmt}"
        return ([self.folder / f"{n}{suffix}" for n in names] if video else None,
                [self.folder / f"{n}_final.png" for n in names] if final else None)


def _writable_folder(folder: Path, flag: str) -> None:
    check_writable_folder(folder, f"{flag} {folder}")


def save_target(save_path: str, fmt: str | None) -> SaveTarget:
    """Resolve -s (its folder is checked and made apart, by _writable_folder): a name with an extension is a video file (.mp4/.gif), anything else a
    folder; so is a name ending in / (renders.v2/) or an existing folder."""
    from pursuit_mj.render.video import VIDEO_CODECS

    path = Path(save_path)
    folder_meant = save_path.endswith(("/", os.sep)) or path.is_dir()
    if path.suffix and not folder_meant:
        suffix = path.suffix.lower().lstrip(".")
        if suffix not in VIDEO_CODECS:
            raise ValueError(f"-s {save_path}: unknown video extension {path.suffix!r} (use .mp4 or .gif, which "
                             f"--final-frame follows with _final.png; for a folder end the name with /: -s {save_path}/)")
        if fmt is not None and fmt != suffix:
            raise ValueError(f"--format {fmt} contradicts -s {save_path}")
        target = SaveTarget(path.parent, path.stem, suffix, path.suffix)
    else:
        target = SaveTarget(path, None, fmt or "mp4")
    return target


def check_render_settings(settings, config: TaskConfig) -> None:
    """Refuse a bad size or an unknown --camera against the task's own scene, before any episode runs."""
    from pursuit_mj.render.renderer import check_settings

    check_settings(settings, config, load_layout(config.layout))


# ---------------------------------------------------------------------- run


def table_episode_seeds(config, seed: int, episodes: int) -> list[int]:
    """The seeds of episodes 0..episodes-1 that `eval --seed seed` plays on config's layout: render
    --seed S shows the first episodes of that table."""
    from pursuit_mj.evaluation import episode_seeds, layout_seed

    return episode_seeds(layout_seed(seed, config.layout), episodes).tolist()


def run(args) -> int:
    """The render command. Refused or failed before it wrote anything, it leaves none of the folders
    it made for -s or --rerun (what it wrote stays: io_utils.no_new_empty_folders)."""
    with no_new_empty_folders():
        return _run(args)


def _refuse_repeated_seeds(seeds: list[int]) -> None:
    """ValueError naming the first --episode-seed given twice: it would play the episode again
    and write its files over the first's (one name per seed)."""
    seen: set[int] = set()
    for n in seeds:
        if n in seen:
            raise ValueError(f"--episode-seed {n}: given twice (each seed plays one episode, named _episode{n})")
        seen.add(n)


def _run(args) -> int:
    from pursuit_mj.render.episodes import EpisodeOutputs, run_episodes
    from pursuit_mj.render.renderer import RenderSettings
    from pursuit_mj.render.video import check_frame_size, check_video_fps, ensure_ffmpeg

    seeds = args.episode_seeds
    _refuse_repeated_seeds(seeds or [])
    if seeds and args.episodes is not None and args.episodes != len(seeds):
        raise ValueError(f"--episodes {args.episodes} and {len(seeds)} --episode-seed: give one or the other "
                         f"(with --episode-seed, one episode per seed)")
    episodes = len(seeds) if seeds else 1 if args.episodes is None else args.episodes
    check_episodes(episodes)
    if args.trail < 0:
        raise ValueError(f"--trail: expected an integer >= 0, got {args.trail}")
    if args.fps is not None and not args.fps > 0:
        raise ValueError(f"--fps: expected a positive number, got {args.fps}")
    train_cfg = _train_config(args.model_config, args) if args.model_config else None
    config = task_config(args, train_cfg.task if train_cfg is not None else None)
    if train_cfg is not None:
        _refuse_a_layout_the_run_never_met(args, train_cfg, config)
    load_layout(config.layout)
    video, final = not args.no_video, args.final_frame
    fps = args.fps or 1.0 / config.control_dt
    if not (video or final or args.rerun):
        raise ValueError("--no-video without --final-frame or --rerun leaves nothing to write")
    settings = RenderSettings(args.width, args.height, args.camera, args.quality, key=not args.no_key)
    [(policy, label)] = shield_each_if_asked(args, [choose_policy(args, config, train_cfg)], config,
                                             "render plays one policy")  # before any folder is made
    target = save_target(args.save_path, args.format) if video or final else None
    if target is not None:
        check_render_settings(settings, config)  # the size range first: an odd size matters only inside it
        if video:
            check_frame_size(target.fmt, args.width, args.height)
            check_video_fps(target.fmt, fps, "--fps" if args.fps else f"--fps (default 1/control_dt = {fps:g})")
            ensure_ffmpeg()
    if args.rerun and target is not None:
        rrd, folder = Path(args.rerun).resolve(), target.folder.resolve()
        if rrd == folder or rrd in folder.parents:
            raise ValueError(f"-s {args.save_path} and --rerun {args.rerun}: the recording would be written where -s makes its folder")
    # the checks that make folders last, so that bad input leaves none behind
    if args.rerun:
        from pursuit_mj.recording import RerunEpisodeRecording, check_rrd_path

        check_rrd_path(args.rerun, "--rerun", episodes=True)
    if target is not None:
        _writable_folder(target.folder, "-s")
        sweep_dead_parts(target.folder, "-s")
    videos = finals = None
    if target is not None:
        task_tag = "".join(f"_{Path(f).stem}" for f in args.task_files or [])  # --task hard: not the default task's files
        frames = {**dataclasses.asdict(settings), "fps": fps, "trail": args.trail, "format": target.fmt}
        factory = policy_file_name(args.policy) if args.policy is not None and is_policy_file(args.policy) else None
        if factory is not None and seeds:  # NAME(config, seed) was given --seed, which these names leave out
            factory = f"{factory} seed {args.seed}"
        # an evader model of one's own is made as NAME(config, n_worlds, seed) with --seed, which these names leave out
        evader_seed = args.seed if seeds else None
        digest = render_digest(config, label, checkpoint_file(args, train_cfg), frames, factory, evader_seed)
        if seeds:  # each file is named after its episode's seed; --seed plays no part but in a file of one's own
            stem = f"{label}{task_tag}_layout{layout_tag(config)}_{config.fidelity}_{digest}"
            videos, finals = target.paths(episodes, stem, video, final, [f"episode{n}" for n in seeds])
        else:
            stem = f"{label}{task_tag}_layout{layout_tag(config)}_{config.fidelity}_seed{args.seed}_{digest}"
            videos, finals = target.paths(episodes, stem, video, final)
        for path in (videos or []) + (finals or []):
            if path.is_dir():  # found now, not by the rename after the episode is played
                raise ValueError(f"-s {args.save_path}: {path} is a folder, expected a file name there")
    outputs = EpisodeOutputs(videos, finals, fps=fps, trail_length=args.trail)

    def report(k, record, written) -> None:
        where = ", ".join(str(p) for p in written)
        print(f"episode {k}: {record.outcome} after {record.steps} steps (seed {record.seed})" + (f" -> {where}" if where else ""), flush=True)

    # its trail_length counts positions: N decision steps are N + 1 of them, as in the frames
    recording = RerunEpisodeRecording(args.rerun, trail_length=args.trail + 1) if args.rerun else None
    where = "a built-in layout drawn per episode" if config.random_layout else f"layout {config.layout}"
    task = task_named(args, f"of -mc {args.model_config}" if args.model_config else "")  # the -mc run's task is the base
    print(f"render: {label} on {where}, {config.fidelity} fidelity, {task}", flush=True)  # what the episode lines below are of
    ok = False
    try:
        run_episodes(config, policy, episodes, args.seed, settings, outputs, recording, label, on_episode=report,
                     episode_seeds=seeds or table_episode_seeds(config, args.seed, episodes))
        ok = True
    finally:
        if recording is not None:
            path = recording.close(ok=ok)
            if path is not None or (recording.lost is not None and recording.n_episodes):  # else the error says it
                print(recording.summary(), file=sys.stdout if ok else sys.stderr, flush=True)
    return 0
