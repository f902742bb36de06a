"""Which rollout backend runs the shared cost: ``--device cpu|cuda|auto``.

The cost module (:mod:`~amhe_cli.estimation.cost`, paper eq. 1 / eq. 4) rolls
every candidate out over every clip through one *rollout backend*; nothing above
it knows which one ran. Two exist:

* ``cpu``: :class:`~amhe_cli.model.rollout.RolloutPool`, ``mujoco.rollout`` on a
  thread pool (always available).
* ``cuda``: :class:`~amhe_cli.model.rollout_warp.WarpRollout`, MuJoCo Warp with
  candidates × clips as the worlds of one batched model (needs ``amhe[gpu]`` and
  a CUDA device; docs/gpu.md).

``auto`` (the default) picks ``cuda`` where both are present, else ``cpu``; the
choice is printed once per process to stderr.
"""

from __future__ import annotations

import importlib.util
import sys

from amhe_cli.errors import AmheError

DEVICES = ("auto", "cpu", "cuda")

_announced: set[str] = set()
#: The process's device when none is given (``--device`` sets it): (resolved device, announce it).
_default = {"device": "cpu", "announce": False}


def set_default(requested: str | None) -> str:
    """Resolve ``requested`` (:func:`choose_device`) and make it the device of every backend created
    without one (the cost module's, the MHE's); such backends then announce it once.

    Raises:
        AmheError: as :func:`choose_device`.
    """
    _default["device"] = choose_device(requested)
    _default["announce"] = True
    return _default["device"]


def default_device() -> str:
    """The device a backend created without one runs on (``cpu`` unless :func:`set_default` said else)."""
    return _default["device"]


def gpu_packages() -> str | None:
    """None when ``mujoco_warp`` and ``warp`` are importable, else a one-line reason."""
    missing = [m for m in ("warp", "mujoco_warp") if importlib.util.find_spec(m) is None]
    if missing:
        return f"{' and '.join(missing)} not installed (pip install 'amhe[gpu]')"
    return None


def cuda_device() -> str | None:
    """Name of the first CUDA device Warp sees, or None (also when Warp is not installed)."""
    if gpu_packages() is not None:
        return None
    from amhe_cli.model.rollout_warp import _quiet, warp_device
    if warp_device() == "cpu":
        return "Warp CPU device (AMHE_WARP_DEVICE=cpu)"
    try:
        import warp as wp
        _quiet(wp)
        wp.init()
        if wp.get_cuda_device_count() < 1:
            return None
        return str(wp.get_device("cuda:0").name)
    except Exception:  # a broken driver reads as no device: auto falls back to the CPU
        return None


def choose_device(requested: str | None, *, packages: str | None | bool = False,
                  device_name: str | None | bool = False) -> str:
    """Resolve ``--device``: ``"cpu"`` or ``"cuda"``.

    Args:
        requested: ``"auto"`` (or None), ``"cpu"`` or ``"cuda"``.
        packages, device_name: for tests, what :func:`gpu_packages` and
            :func:`cuda_device` would return (False: ask them).

    Raises:
        AmheError: an unknown device, or ``cuda`` asked for where the GPU
            packages or a CUDA device are missing (the line says which).
    """
    req = (requested or "auto").lower()
    if req not in DEVICES:
        raise AmheError(f"--device {requested!r}: expected one of {', '.join(DEVICES)}")
    if req == "cpu":
        return "cpu"
    why = gpu_packages() if packages is False else packages
    name = None
    if why is None:
        name = cuda_device() if device_name is False else device_name
        if name is None:
            why = "no CUDA device found"
    if why is not None:
        if req == "cuda":
            raise AmheError(f"--device cuda: {why}")
        return "cpu"
    return "cuda"


def announce(device: str, detail: str) -> None:
    """Print ``rollouts on DEVICE (detail)`` to stderr, once per process and device."""
    if device in _announced:
        return
    _announced.add(device)
    print(f"amhe: rollouts on {device} ({detail})", file=sys.stderr, flush=True)


def make_backend(model, device: str | None = None, nthread: int | None = None):
    """A rollout backend for ``model`` on ``device`` (resolved by :func:`choose_device`; None: the
    process default, :func:`set_default`).

    Returns:
        a :class:`~amhe_cli.model.rollout.RolloutPool` (cpu) or a
        :class:`~amhe_cli.model.rollout_warp.WarpRollout` (cuda); both offer
        ``rollout_candidates`` and ``close``.

    Raises:
        AmheError: as :func:`choose_device`, or a scene the Warp backend refuses
            (:func:`~amhe_cli.model.rollout_warp.check_scene`).
    """
    dev = default_device() if device is None else choose_device(device)
    if dev == "cuda":
        from amhe_cli.model.rollout_warp import WarpRollout, warp_device
        backend = WarpRollout(model, device=warp_device())
    else:
        from amhe_cli.model.rollout import RolloutPool
        backend = RolloutPool(model, nthread)
    if (_default["announce"] if device is None else device != "cpu"):  # a choice was made: say which
        announce(dev, backend.describe())
    return backend
