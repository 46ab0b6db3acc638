"""A true stick–slip reference, written without the package: a mass with viscous damping, Coulomb friction while
it slides and any force up to the static level held at rest (v = 0 and x constant exactly), integrated piecewise
by scipy with events at the switches (Karnopp's model).  Used by tests/test_load.py and scripts/bench_at_rest.py."""
from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp


def stick_slip(m, c, fc_pos, fc_neg, u, load, t_eval):
    """x and v at ``t_eval`` of m·v' = −c·v + u(t) + load(x) − F with Coulomb friction ±fc while sliding and any
    force up to fc± held at rest (static = Coulomb, as the coulomb model): v = 0 and x constant exactly while
    −fc_neg ≤ u + load ≤ fc_pos.  Karnopp's switching, integrated piecewise with events; from rest at x = 0."""
    t, x, v, t_end = t_eval[0], 0.0, 0.0, t_eval[-1]
    out_x, out_v = np.full(t_eval.size, np.nan), np.full(t_eval.size, np.nan)
    while t < t_end:
        net = u(t) + load(x)
        if v == 0.0 and -fc_neg <= net <= fc_pos:  # stuck until the net force leaves the band
            def leave_pos(s, _):
                return u(s) + load(x) - fc_pos

            def leave_neg(s, _):
                return u(s) + load(x) + fc_neg
            leave_pos.terminal = leave_neg.terminal = True
            sol = solve_ivp(lambda s, y: [0.0], (t, t_end), [0.0], events=(leave_pos, leave_neg), max_step=1e-3,
                            rtol=1e-12, atol=1e-14)
            inside = (t_eval >= t) & (t_eval <= sol.t[-1])
            out_x[inside], out_v[inside] = x, 0.0
            if sol.status != 1:
                break
            t = sol.t[-1]
            direction = 1.0 if sol.t_events[0].size else -1.0
        else:
            direction = np.sign(v) if v != 0.0 else np.sign(net)
        fc = fc_pos if direction > 0 else fc_neg

        def rhs(s, y, d=direction, f=fc):
            return [y[1], (-c * y[1] + u(s) + load(y[0]) - d * f) / m]

        def stops(s, y, d=direction):
            return y[1] * d if s > t else 1.0
        stops.terminal, stops.direction = True, -1
        sol = solve_ivp(rhs, (t, t_end), [x, v], events=stops, dense_output=True, rtol=1e-11, atol=1e-14,
                        max_step=1e-3)
        inside = (t_eval >= t) & (t_eval <= sol.t[-1])
        out_x[inside], out_v[inside] = sol.sol(t_eval[inside])
        if sol.status != 1:
            break
        t, x, v = sol.t[-1], sol.y[0, -1], 0.0
    return out_x, out_v
