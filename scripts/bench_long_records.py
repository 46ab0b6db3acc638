"""Long, fast records: the same experiment logged at 100 Hz, 1 kHz and 10 kHz (60 s: 6·10³, 6·10⁴ and 6·10⁵
samples), selected and identified — the structure chosen, the parameters with their 95 % intervals, the times.

g1 (G = 10/(s + 10), Coulomb friction 0.5/0.4 N) driven in open loop by two tones per half (1 and 3.1 Hz, then
0.6 and 4.3 Hz), its velocity measured with white noise of one power spectral density at every rate (40 dB below
the signal at 100 Hz, the same noise in the band at the higher rates), a second experiment of other seeds to
validate on.  `select` over the default candidates, then `identify --method pso` of the chosen structure.

Usage: python scripts/bench_long_records.py [--seconds 60] [--rates 100,1000,10000] [--out docs/bench-long-records.md]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

import servofmu as sf
from servofmu.identification.criterion import record_data
from servofmu.identification.shortening import reduction_factor
from servofmu.measurement.datafile import read_data_file
from servofmu.measurement.records import import_records
from servofmu.runtime import RunOptions
from servofmu.simulation.batch import BatchSimulator

SNR_DB = 40.0


def experiment(folder: Path, name: str, rate: float, seconds: float, seed: int) -> Path:
    """One record of g1 at ``rate`` (Hz) as a records file."""
    g1 = sf.load_plant("g1")
    dt = 1.0 / rate
    t = np.arange(0.0, seconds, dt)
    u = np.where(t < seconds / 2, 2 * np.sin(2 * np.pi * t) + 0.6 * np.sin(2 * np.pi * 3.1 * t),
                 0.7 * np.sin(2 * np.pi * 0.6 * t) + 0.3 * np.sin(2 * np.pi * 4.3 * t))
    v = BatchSimulator(g1).simulate_record(g1.parameter_vector()[None], t, u, rtol=1e-10).v[0]
    sigma = np.std(v) * 10 ** (-SNR_DB / 20) * np.sqrt(rate / 100.0)  # one noise density at every rate
    v = v + sigma * np.random.default_rng(seed).standard_normal(v.size)
    csv = folder / f"{name}.csv"
    np.savetxt(csv, np.column_stack([t, u, v]), delimiter=",", header="t,u,v", comments="", fmt="%.17g")
    out = folder / f"{name}.h5"
    import_records([csv], out, "t", "u", "v", kind="velocity")
    csv.unlink()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--rates", default="100,1000,10000")
    ap.add_argument("--out", type=Path, default=Path("docs/bench-long-records.md"))
    args = ap.parse_args()
    rates = [float(r) for r in args.rates.split(",")]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for rate in rates:
            fit = experiment(folder, f"fit{rate:g}", rate, args.seconds, 1)
            val = experiment(folder, f"val{rate:g}", rate, args.seconds, 2)
            t0 = time.perf_counter()
            selection = sf.select_files([fit], val, folder / f"select{rate:g}.h5", sf.SelectOptions(),
                                        RunOptions(workers=2))
            select_s = time.perf_counter() - t0
            t0 = time.perf_counter()
            est = sf.PSOANNIdentifier(sf.load_plant(folder / f"select{rate:g}.toml"), method="pso", seed=0)
            est.fit(record_data(read_data_file(fit)))
            identify_s = time.perf_counter() - t0
            q = reduction_factor(record_data(read_data_file(fit)).records[0])
            rows.append((rate, int(args.seconds * rate), selection.chosen.name, selection.ranked_share, q, select_s,
                         identify_s, dict(zip(est.names_, zip(est.theta_, est.intervals_)))))
            print(rows[-1][:7], flush=True)
    base = rows[0]
    lines = ["# Long records: one experiment at 100 Hz, 1 kHz and 10 kHz", "",
             f"`python scripts/bench_long_records.py --seconds {args.seconds:g}` on a 2-core machine: g1 in open loop, "
             f"{args.seconds:g} s, velocity noise of one density at every rate (40 dB at 100 Hz); `select` over the "
             "default candidates (the ranking on at most 4000 fitted samples: the record at 40 samples per period "
             "of its input's band, then its first share; the chosen structure polished on every sample), then "
             "`identify --method pso` of the chosen structure (its swarm on the reduced record, its polish on every "
             "sample). Ratios against the 100 Hz record of the same run.", "",
             "| rate (Hz) | samples | chosen | ranked on (share of samples) | rate reduced by | select (s) | × 100 Hz "
             "| identify (s) | × 100 Hz |", "|---|---|---|---|---|---|---|---|---|"]
    for rate, n, chosen, share, q, sel, ide, _ in rows:
        lines.append(f"| {rate:g} | {n} | {chosen} | {share:.3g} | {q} | {sel:.1f} | {sel / base[5]:.2f} | "
                     f"{ide:.1f} | {ide / base[6]:.2f} |")
    lines += ["", "The parameters identified (95 % intervals); truth: pole1 −10, dc_gain 1, fc_pos 0.5, fc_neg 0.4.", "",
              "| rate (Hz) | " + " | ".join(base[7]) + " |", "|---|" + "---|" * len(base[7])]
    for rate, *_, params in rows:
        lines.append(f"| {rate:g} | " + " | ".join(f"{v:.5g} [{i[0]:.5g}, {i[1]:.5g}]" for v, i in params.values())
                     + " |")
    args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
