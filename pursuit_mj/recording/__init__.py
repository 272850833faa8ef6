"""Recorders that only read simulation state: rerun episode recordings and training scalar logs."""

from .env_recorder import EnvRecorder
from .rerun_episodes import EpisodeBuffer, RerunEpisodeRecording, check_rrd_path
from .rerun_scalars import RerunScalarLogger

__all__ = ["EnvRecorder", "EpisodeBuffer", "RerunEpisodeRecording", "RerunScalarLogger", "check_rrd_path"]
