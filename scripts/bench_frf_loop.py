"""The plant's frequency response from a drive's log in its loop (`servofmu frf --closed-loop`), against the
noise-free truth: the demo's axis (linear_axis on an incline, axis_controller, test pulses, 1 µm encoder) co-simulated
on libcosim as `servofmu demo` does, once with the drive's actuator noise (1.5 N RMS, about 40 dB below the force
command) and once without, each logged as the drive would and imported.

For each external signal r — the reference, and the injected test pulses (`--external disturbance`) — the truth is
the noise-free log's own estimate G_r0 = S_ry/S_ru: the BLA of the axis in this loop for this excitation (friction
makes it depend on the signal; the noise is what the band must cover).  On the noisy log, at every Welch frequency
where γ²_ru ≥ 0.9 (TRUSTED_COHERENCE), this counts where |G_r − G_r0| ≤ 2σ_r (the estimate from r and its own
standard deviation), gives the direct estimate's (S_uy/S_uu) error beside it, which the noise fed back through the
controller biases, and the same for the local polynomial method from r (its 95 % band, where it bounds G).  A Bode
figure of the estimate from the pulses goes to docs/figures/frf-closed-loop-demo.png.

Usage: python scripts/bench_frf_loop.py [--seeds 5] [--figure docs/figures/frf-closed-loop-demo.png]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from servofmu.broadband.records_frf import EXTERNAL_SIGNALS, TRUSTED_COHERENCE, records_frf
from servofmu.commands.demo import (DEMO_AXIS_LOAD, FORCE_CONSTANT, REST, demo_pulses, reference_trajectories,
                                    resting_first, write_drive_log)
from servofmu.control.cosim import cosimulate
from servofmu.control.fmus import build_controller_fmu
from servofmu.control.system import write_system
from servofmu.fmu import build_fmu
from servofmu.measurement.records import LoopChannels, import_records
from servofmu.model.controller import load_controller
from servofmu.model.plant import load_plant
from servofmu.runtime import RunOptions

ROOT = Path(__file__).resolve().parent.parent


def logged(folder: Path, name: str, noise: float, seed: int) -> dict:
    """The demo's identification run co-simulated with actuator noise ``noise`` (N RMS), logged and imported: its
    records_frf estimates from each external signal (the reference, the injected test pulses)."""
    controller = load_controller("axis_controller").with_values(force_noise=noise, noise_seed=seed)
    reference = resting_first(reference_trajectories(controller.sample_time)["identify"], REST)
    ssp = write_system(folder / "axis.fmu", folder / "controller.fmu", reference, folder / f"{name}.ssp",
                       controller=controller, overwrite=True, disturbance=demo_pulses(reference[0]))
    log = write_drive_log(cosimulate(ssp, engine="libcosim"), folder / f"{name}.csv", seed)
    loop = LoopChannels(reference="reference", disturbance="pulse_V", input_scale=FORCE_CONSTANT,
                        disturbance_scale=FORCE_CONSTANT)
    data = import_records([log], folder / f"{name}.h5", time="stamp", input="command_V", output_column="encoder",
                          kind="position", loop=loop, run=RunOptions(overwrite=True))
    return {external: records_frf(data, closed_loop=True, external=external)[1][0] for external in EXTERNAL_SIGNALS}


def at(frequencies, estimate) -> np.ndarray:
    """``estimate``'s G interpolated (real and imaginary parts) at ``frequencies``: two logs' grids may differ by a
    line."""
    return np.interp(frequencies, estimate.frequencies, estimate.G.real) + 1j * np.interp(
        frequencies, estimate.frequencies, estimate.G.imag)


def compare(noisy, truth) -> dict:
    """Shares and errors on the noisy log's trusted frequencies (module docstring)."""
    cl, cl0 = noisy.closed_loop, truth.closed_loop
    good = cl.coherence_ru >= TRUSTED_COHERENCE
    if not good.any():
        return {"trusted": 0, "of": int(good.size)}
    g0 = at(cl.frequencies[good], cl0)
    within = np.abs(cl.G[good] - g0) <= 2 * np.sqrt(cl.var[good])
    direct = at(cl.frequencies, noisy.direct)
    out = {"trusted": int(good.sum()), "of": int(good.size), "band": (float(cl.frequencies[good].min()),
                                                                         float(cl.frequencies[good].max())),
           "within": float(np.mean(within)), "error_reference": float(np.median(np.abs(cl.G[good] / g0 - 1))),
           "error_direct": float(np.median(np.abs(direct[good] / g0 - 1)))}
    lpm, lpm0 = noisy.lpm, truth.lpm
    if lpm is not None and lpm0 is not None:
        centre, radius = lpm.band()
        bounded = np.isfinite(radius)
        lines = bounded & (lpm.frequencies <= out["band"][1])
        out["lpm_bounded"] = float(np.mean(bounded[lpm.frequencies <= out["band"][1]]))
        truth_lpm = at(lpm.frequencies, lpm0)
        out["lpm_within"] = float(np.mean(np.abs(centre[lines] - truth_lpm[lines]) <= radius[lines])) \
            if lines.any() else float("nan")
    return out


def figure(noisy, truth, path: Path) -> None:
    """Bode magnitude and phase: the noise-free truth, the estimate from the reference with ±2σ (noisy log), the
    direct estimate (noisy log), and the frequencies where γ²_ru ≥ 0.9 marked."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cl, cl0, d = noisy.closed_loop, truth.closed_loop, noisy.direct
    good = cl.coherence_ru >= TRUSTED_COHERENCE
    top = 1.5 * float(cl.frequencies[good].max())  # above, the pulses' lines carry noise alone: phase is noise
    sd = np.sqrt(cl.var)
    fig, (mag, phase) = plt.subplots(2, 1, sharex=True, figsize=(8, 6.5))
    mag.fill_between(cl.frequencies, np.maximum(np.abs(cl.G) - 2 * sd, 1e-12), np.abs(cl.G) + 2 * sd, alpha=0.25,
                     color="C0", label="from the test pulses ± 2σ (noisy log)")
    mag.loglog(cl.frequencies, np.abs(cl.G), "C0-", lw=1)
    mag.loglog(cl0.frequencies, np.abs(cl0.G), "k--", lw=1.2, label="from the test pulses, noise-free log (truth)")
    mag.loglog(d.frequencies, np.abs(d.G), "C3-", lw=1, label="direct S_uy/S_uu (noisy log)")
    mag.loglog(cl.frequencies[good], np.abs(cl.G[good]), "C0o", ms=3, label=f"γ²_du ≥ {TRUSTED_COHERENCE}")
    mag.set_ylabel("|G| (m/(N·s))")
    mag.legend(fontsize=8)
    mag.grid(True, which="both", alpha=0.3)
    for est, style in ((cl, "C0-"), (cl0, "k--"), (d, "C3-")):
        shown = est.frequencies <= top
        phase.semilogx(est.frequencies[shown], np.degrees(np.unwrap(np.angle(est.G[shown]))), style, lw=1)
    mag.set_xlim(cl.frequencies[0], top)
    phase.set_ylabel("phase (°)")
    phase.set_xlabel("frequency (Hz)")
    phase.grid(True, which="both", alpha=0.3)
    fig.suptitle("The demo's axis in its loop: the plant's response from the drive's log")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5, help="noise seeds of the noisy log")
    ap.add_argument("--figure", type=Path, default=ROOT / "docs" / "figures" / "frf-closed-loop-demo.png")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        axis = load_plant("linear_axis").to_toml().replace('name = "linear_axis"', 'name = "inclined_linear_axis"')
        (folder / "axis.toml").write_text(axis + DEMO_AXIS_LOAD)
        build_fmu(load_plant(folder / "axis.toml"), folder / "axis.fmu", fmi_version=2, overwrite=True)
        build_controller_fmu(load_controller("axis_controller"), folder / "controller.fmu", fmi_version=2,
                             overwrite=True)
        t0 = time.perf_counter()
        truth = logged(folder, "noise-free", 0.0, 0)
        print("| external signal r | noise seed | frequencies with γ²_ru ≥ 0.9 | their band (Hz) | within ±2σ of "
              "the truth | median error from r | median error direct | LPM from r: share bounded / within its band |")
        print("|---|---|---|---|---|---|---|---|")
        pooled = {external: [0, 0] for external in EXTERNAL_SIGNALS}  # lines within ±2σ, lines trusted
        for seed in range(args.seeds):
            noisy = logged(folder, f"noisy-{seed}", 1.5, seed)
            for external in EXTERNAL_SIGNALS:
                c = compare(noisy[external], truth[external])
                pooled[external][0] += round(c.get("within", 0.0) * c["trusted"])
                pooled[external][1] += c["trusted"]
                if not c["trusted"]:
                    print(f"| {external} | {seed} | 0 of {c['of']} | – | – | – | – | – |", flush=True)
                    continue
                print(f"| {external} | {seed} | {c['trusted']} of {c['of']} | "
                      f"{c['band'][0]:.3g}–{c['band'][1]:.3g} | "
                      f"{100 * c['within']:.1f} % | {c['error_reference']:.3g} | {c['error_direct']:.3g} | "
                      f"{100 * c.get('lpm_bounded', float('nan')):.0f} % / "
                      f"{100 * c.get('lpm_within', float('nan')):.0f} % |", flush=True)
            if seed == 0:
                figure(noisy["disturbance"], truth["disturbance"], args.figure)
        for external, (within, trusted) in pooled.items():
            print(f"\n{external}: {within} of {trusted} trusted lines over the seeds within ±2σ of the truth"
                  + (f" ({100 * within / trusted:.1f} %)" if trusted else ""))
        print(f"\n{args.seeds + 1} co-simulations and estimates: {time.perf_counter() - t0:.0f} s; "
              f"figure {args.figure}")


if __name__ == "__main__":
    main()
