"""Synthetic indoor RGB-D data: procedural rooms, a CPU ray caster, camera paths, sequences and shards.

The embedded default dataset of codeslam (training, tests, demo); see :mod:`codeslam.synth.render` for why
a torch ray caster. Entry points: :func:`build_scene`, :func:`render`, :func:`random_trajectory`,
:func:`random_views`, :func:`preset_trajectory` (motion presets: handheld, walk, fast-turn),
:func:`generate_sequences`, :func:`write_shards`, :func:`read_shard`.
"""

from codeslam.synth.generate import generate_sequence, generate_sequences
from codeslam.synth.motion import PRESETS, MotionPreset, preset_trajectory
from codeslam.synth.render import RenderConfig, render
from codeslam.synth.scene import RoomSize, Scene, build_scene
from codeslam.synth.shards import ShardSpec, read_shard, write_shards
from codeslam.synth.trajectory import look_at, random_trajectory, random_views

__all__ = [
    "PRESETS", "MotionPreset", "RenderConfig", "RoomSize", "Scene", "ShardSpec", "build_scene", "generate_sequence",
    "generate_sequences", "look_at", "preset_trajectory", "random_trajectory", "random_views", "read_shard", "render",
    "write_shards",
]
