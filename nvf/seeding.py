"""Seeded random generators (PROTOCOL.md 3): every draw of a run, in training, planning and
evaluation, comes from a generator seeded from ``(run seed, step, purpose)``, so a resumed run draws
exactly what an uninterrupted one would."""

import functools
import hashlib
from collections.abc import Callable

import torch

GeneratorFactory = Callable[[str], torch.Generator]  # purpose -> a fresh generator for one step


def seeded_generator(seed: int, step: int, purpose: str, device: torch.device | str = "cpu") -> torch.Generator:
    """Generator seeded from ``(seed, step, purpose)`` via SHA-256 (stable across processes)."""
    digest = hashlib.sha256(f"{seed}/{step}/{purpose}".encode()).digest()
    generator = torch.Generator(device=device)
    generator.manual_seed(int.from_bytes(digest[:8], "little") & ((1 << 63) - 1))
    return generator


def generator_factory(seed: int, step: int, device: torch.device | str = "cpu") -> GeneratorFactory:
    """``purpose -> seeded_generator(seed, step, purpose, device)`` for one planning step."""
    return functools.partial(seeded_generator, seed, step, device=device)
