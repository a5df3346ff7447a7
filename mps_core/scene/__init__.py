"""Scenes: TOML in, a validated :class:`Scene` in SI units out (:mod:`.scene`), with the run
settings it holds (:mod:`.settings`) and the presets that ship (``presets/*.toml``)."""

from .scene import EffectSpec, Scene, load_scene, preset_names, scene_from_dict, scene_from_text

__all__ = ["Scene", "EffectSpec", "load_scene", "preset_names", "scene_from_dict", "scene_from_text"]
