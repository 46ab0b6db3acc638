"""An independent reference for the plant equations (docs/model.md), written without the package:
scipy's state-space realisation of G(s) and scipy's Radau integrator."""
from __future__ import annotations

import numpy as np
from scipy import signal
from scipy.integrate import solve_ivp


def friction(v, z, fr):
    """F(v) and, for LuGre, dz/dt — the equations of docs/model.md written out again."""
    def g(side):
        fc = fr[f"fc_{side}"]
        if fr["model"] == "coulomb":
            return fc
        return fc + (fr[f"fs_{side}"] - fc) * np.exp(-(v / fr["vs"]) ** 2)

    fv = fr.get("fv", 0.0)
    if fr["model"] == "lugre":
        gv = g("pos") if v >= 0 else g("neg")
        dz = v - fr["sigma0"] * abs(v) * z / gv
        return fr["sigma0"] * z + fr["sigma1"] * dz + fv * v, dz
    t = np.tanh(v / fr.get("v_smooth", 1e-3))
    return g("pos") * max(t, 0.0) + g("neg") * min(t, 0.0) + fv * v, 0.0


def simulate_reference(poles, zeros, k, fr, amplitude, frequency, t_eval, u=0.0, rtol=1e-10, atol=1e-12):
    """v(t) of the plant G(s) = k·∏(s−z)/∏(s−p) with friction ``fr`` (a dict of plant-file keys)."""
    A, B, C, D = signal.zpk2ss(zeros, poles, k)
    n = A.shape[0]
    lugre = fr["model"] == "lugre"

    def rhs(t, s):
        x, z = s[:n], s[n] if lugre else 0.0
        v = float((C @ x)[0])
        force, dz = friction(v, z, fr)
        w = u + amplitude * np.sin(2 * np.pi * frequency * t) - force
        dx = A @ x + B[:, 0] * w
        return np.concatenate([dx, [dz]]) if lugre else dx

    def jac(t, s):
        # Exact for the linear part; the scalar friction law is differentiated by central differences.
        x, z = s[:n], s[n] if lugre else 0.0
        v = float((C @ x)[0])
        hv, hz = 1e-7 * max(1.0, abs(v)), 1e-9
        dF_dv = (friction(v + hv, z, fr)[0] - friction(v - hv, z, fr)[0]) / (2 * hv)
        J = np.zeros((len(s), len(s)))
        J[:n, :n] = A - np.outer(B[:, 0], C[0]) * dF_dv
        if lugre:
            ddz_dv = (friction(v + hv, z, fr)[1] - friction(v - hv, z, fr)[1]) / (2 * hv)
            dF_dz = (friction(v, z + hz, fr)[0] - friction(v, z - hz, fr)[0]) / (2 * hz)
            ddz_dz = (friction(v, z + hz, fr)[1] - friction(v, z - hz, fr)[1]) / (2 * hz)
            J[:n, n] = -B[:, 0] * dF_dz
            J[n, :n] = ddz_dv * C[0]
            J[n, n] = ddz_dz
        return J

    s0 = np.zeros(n + (1 if lugre else 0))
    sol = solve_ivp(rhs, (t_eval[0], t_eval[-1]), s0, method="Radau", t_eval=t_eval, rtol=rtol, atol=atol, jac=jac)
    assert sol.success, sol.message
    return (C @ sol.y[:n]).ravel()


def gain_from_dc(poles, zeros, dc_gain):
    return dc_gain * np.real(np.prod(-np.asarray(poles))) / (np.real(np.prod(-np.asarray(zeros))) if len(zeros) else 1.0)


def simulate_reference_input(poles, zeros, k, fr, t, u, rtol=1e-10, atol=1e-12):
    """v at the times ``t`` when the plant is driven by the input samples ``u`` (linear between samples)."""
    A, B, C, D = signal.zpk2ss(zeros, poles, k)
    n = A.shape[0]

    def rhs(time, x):
        v = float((C @ x)[0])
        force, _ = friction(v, 0.0, fr)
        return A @ x + B[:, 0] * (np.interp(time, t, u) - force)

    sol = solve_ivp(rhs, (t[0], t[-1]), np.zeros(n), method="Radau", t_eval=t, rtol=rtol, atol=atol,
                    max_step=float(np.min(np.diff(t))))
    assert sol.success, sol.message
    return (C @ sol.y).ravel()
