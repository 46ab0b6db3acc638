"""The axis in its loop, simulated for many plants at once: the batch simulator's plant with the drive's
controller law (batch_c/controller_law.h) at every sample (batch_c/loop_driver.c).

The loop reproduces the co-simulation of servofmu.control.cosim exactly — sampling, delay, saturation, the
Jacobi exchange — so that a candidate plant simulated in the known loop from the recorded reference can be
compared with the recorded position and force command (servofmu.identification.closed_loop).
"""
from __future__ import annotations

import ctypes
import functools
from dataclasses import dataclass

import numpy as np

from ..errors import UserError
from ..model.controller import ControllerSpec, params_header
from ..model.plant import Plant
from .batch import BatchSimulator
from .compiled import DRIVER_DIR, H_START, c_doubles, c_mask, compiled_driver

__all__ = ["LoopSimulator", "LoopResponse", "CONTROLLER_LAW"]

CONTROLLER_LAW = DRIVER_DIR / "controller_law.h"  # the drive's law in C: compiled here and into the controller FMU


@dataclass(frozen=True)
class LoopResponse:
    """The loop of N plants at the samples: position (m) and velocity (m/s) at t_k, and the force command (N)
    applied on [t_k, t_k+1); each of shape (N, samples)."""

    position: np.ndarray
    v: np.ndarray
    command: np.ndarray


@functools.lru_cache(maxsize=None)
def _loop_library(plant: Plant) -> ctypes.CDLL:
    lib = compiled_driver(plant, DRIVER_DIR / "loop_driver.c",
                          {"controller_params.h": params_header(),
                           "controller_law.h": CONTROLLER_LAW.read_text()})
    d, pd, lng, i = ctypes.c_double, ctypes.POINTER(ctypes.c_double), ctypes.c_long, ctypes.c_int
    lib.sb_loop.argtypes = [lng, i, pd, ctypes.POINTER(ctypes.c_ubyte), lng, pd, pd, pd, pd, pd, d, d, lng, i, pd]
    lib.sb_loop.restype = i
    return lib


class LoopSimulator(BatchSimulator):
    """A batch simulator that can also close the drive's loop around the plant (:meth:`simulate_loop`)."""

    @staticmethod
    def _load(plant: Plant) -> ctypes.CDLL:
        return _loop_library(plant)

    def simulate_loop(self, params, time, reference, controller: ControllerSpec, rtol: float = 1e-8,
                      max_steps: int = 50_000_000, disturbance=None, encoder_error=None) -> LoopResponse:
        """The loop at the sample times ``time`` (uniform, the controller's sample time: a log's own time stamps
        are mapped to that grid by servofmu.identification.closed_loop) following ``reference``, all plant states
        zero at time[0], for every row of ``params``; ``disturbance`` (N, one value per sample, optional) is added
        to the force applied on [t_k, t_k+1) after the output limit, and to the command returned;
        ``encoder_error`` (m, one value per sample, optional) to the position the controller reads at t_k (not to
        the position returned)."""
        p, valid = self._parameter_sets(params)
        t = np.ascontiguousarray(np.asarray(time, dtype=float).ravel())
        r = np.ascontiguousarray(np.asarray(reference, dtype=float).ravel())
        if t.size != r.size or t.size < 2 or not (np.all(np.isfinite(t)) and np.all(np.isfinite(r))):
            raise UserError("a closed-loop run needs at least two finite samples of time and reference")
        d, e = (_per_sample(a, t.size, what) for a, what in ((disturbance, "disturbance"),
                                                            (encoder_error, "encoder error")))
        steps = np.diff(t)
        if np.max(np.abs(steps - controller.sample_time)) > 1e-6 * controller.sample_time:
            raise UserError(f"the samples are {np.median(steps):g} s apart, the controller samples every "
                            f"{controller.sample_time:g} s: the loop needs one record sample per controller sample")
        if not 0 < rtol < 1e-2:
            raise UserError(f"rtol must be in (0, 0.01), not {rtol}")
        cp = np.ascontiguousarray(controller.vector())
        out = np.empty((p.shape[0], 3, t.size))
        rc = self._lib.sb_loop(p.shape[0], p.shape[1], c_doubles(p), c_mask(valid), t.size, c_doubles(t),
                               c_doubles(r), None if d is None else c_doubles(d), None if e is None else c_doubles(e),
                               c_doubles(cp), rtol, H_START, max_steps, self.threads, c_doubles(out))
        if rc != 0:
            raise RuntimeError(f"loop library rejected the call (code {rc})")
        return LoopResponse(position=out[:, 0], v=out[:, 1], command=out[:, 2])


def _per_sample(values, n: int, what: str) -> np.ndarray | None:
    """An optional per-sample signal of the loop as a contiguous array (a UserError if not n finite values)."""
    if values is None:
        return None
    a = np.ascontiguousarray(np.asarray(values, dtype=float).ravel())
    if a.size != n or not np.all(np.isfinite(a)):
        raise UserError(f"a closed-loop {what} needs one finite value per sample")
    return a
