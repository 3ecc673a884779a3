"""Seed 003, dynamic train at 30 km/h: the curve entry of axle 1 under the fuzzy and the
fixed PD, with and without lateral load transfer (the numbers of experiments/seed003.md,
"Why the fuzzy PD loses at 30 km/h").

Usage (from the repository root, PYTHONPATH with orchestrator/ and components/):

    python experiments/figures/seed003_entry.py

The loop is seed003_dynamic_speed.toml's on the pure cores (the order of the FMU run,
which tests/seeds/test_seed_dynamic.py checks equal to it): train outputs -> axle offsets
-> PD -> train step, every 2 ms. Prints, per case, each axle's largest |offset|, the
time axle 1's two wheels spend at their friction limit (|F| >= 0.999 mu Fz), the largest
axle-1 angle, and a trace of axle 1 through the entry (every 50 ms).
"""

import math

from agv_core.axle_pd.fuzzy_pd import AxlePD, FixedGains, FuzzySchedule
from agv_core.axle_pd.track_path import PointErrors, parse_track_path
from agv_core.dynamic_train.dynamic_train import DynamicTrain, TrainDynamics
from agv_core.train.train import TrainGeometry

GEOMETRY = TrainGeometry(5.0, 3.0, 2.1, 9.0)
PATH = f"curve:straight=60,radius=20,angle={math.pi / 2!r}"


def entry(v_kmh, fuzzy, cg_height, h=0.002):
    """Run the loop until axle 4 is 22 m past the curve; one row per step."""
    path = parse_track_path(PATH)
    v = v_kmh / 3.6
    dynamics = TrainDynamics(GEOMETRY, cg_height=cg_height)
    train = DynamicTrain.straight(dynamics, 8.0, 0.0, 0.0)
    train.start(v, (0.0,) * 4)
    probe = PointErrors(path, 4)
    gains = FuzzySchedule() if fuzzy else FixedGains(710.0, 112.0)
    pds = [AxlePD(gains) for _ in range(4)]
    rows = []
    for k in range(int(math.ceil((path.s4 + 22.0) / v / h))):
        points = train.axle_points()
        errors = [p.offset for p in probe.measure(points)]
        u3 = train.car_speeds()[3]
        outputs = [pd.evaluate(e, v if i < 2 else u3) for i, (pd, e) in enumerate(zip(pds, errors))]
        deltas = [o["delta"] for o in outputs]
        _, axle, loads, forces = train._current()
        rows.append({"t": k * h, "e": errors, "delta1": deltas[0],
                     "Kp": math.degrees(outputs[0]["Kp"]), "Kd": math.degrees(outputs[0]["Kd"]),
                     "loads": loads[:2], "use": [abs(f) / (dynamics.mu * fz)
                                                 for f, fz in zip(forces[:2], loads[:2])],
                     "F1": axle[0]})
        train.step(v, deltas, h)
        probe.measure(points, commit=True)
        for pd, e in zip(pds, errors):
            pd.advance(e, h)
    return rows


def main():
    for fuzzy in (True, False):
        for cg_height in (1.2, 0.0):
            rows = entry(30.0, fuzzy, cg_height)
            worst = [max(abs(r["e"][i]) for r in rows) for i in range(4)]
            saturated = [r["t"] for r in rows if min(r["use"]) >= 0.999]
            span = (f"{len(saturated) * 0.002:.2f} s ({saturated[0]:.2f}-{saturated[-1]:.2f} s)"
                    if saturated else "never")
            print(f"\n{'fuzzy' if fuzzy else 'fixed'} PD, cg height {cg_height} m: max |offset| "
                  + " / ".join(f"{100 * w:.2f}" for w in worst) + " cm; axle 1's wheels at "
                  f"the friction limit {span} (peak friction use "
                  f"{max(r['use'][0] for r in rows):.3f} / {max(r['use'][1] for r in rows):.3f}); "
                  "largest axle-1 angle "
                  f"{max(abs(r['delta1']) for r in rows) * 180 / math.pi:.1f} deg")
            print("  t [s]  e1 [cm]  delta1 [deg]  Kp [deg/m]  Kd [deg s/m]  Fz L/R [kN]"
                  "  |F|/mu Fz L/R  F1 [kN]")
            for r in rows:
                if 6.25 <= r["t"] <= 7.05 and round(r["t"] / 0.002) % 25 == 0:
                    angle = math.degrees(r["delta1"])
                    print(f"  {r['t']:.2f}  {100 * r['e'][0]:+7.2f}  {angle:6.1f}"
                          f"  {r['Kp']:6.0f}  {r['Kd']:5.0f}  {r['loads'][0] / 1e3:5.1f} / "
                          f"{r['loads'][1] / 1e3:5.1f}  {r['use'][0]:.3f} / {r['use'][1]:.3f}"
                          f"  {r['F1'] / 1e3:6.1f}")


if __name__ == "__main__":
    main()
