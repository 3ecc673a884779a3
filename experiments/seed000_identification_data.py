"""Write experiments/data/seed000_step.csv: the step response of seed 000 eq (7) (model
c's defaults: eq 6 in SI units, K = 0.6 rad/(V.s), no dead time) to a 1 V step of the
motor command at 0.5 s, sampled every 1 ms for 2 s, plus white measurement noise of
1 mrad (seed 0). Used by experiments/seed000_identification.md and docs/identify.md.

Run: python experiments/seed000_identification_data.py [OUT.csv]
"""

import sys
from pathlib import Path

import numpy as np

from agv_core.steering.actuator import IdentifiedActuator

STEP = 0.001      # [s] sampling
STOP = 2.0        # [s]
T_STEP = 0.5      # [s] the command steps from 0 to 1 V
NOISE = 0.001     # [rad] rms measurement noise
SEED = 0


def step_record(noise=NOISE, seed=SEED):
    """time [s], u [V], alpha [rad] of the eq (7) actuator with measurement noise."""
    act = IdentifiedActuator()
    n = int(round(STOP / STEP)) + 1
    t = STEP * np.arange(n)
    u = np.where(np.arange(n) >= round(T_STEP / STEP), 1.0, 0.0)
    alpha = np.empty(n)
    alpha[0] = act.alpha
    for k in range(n - 1):
        act.step(t[k], STEP, u[k])
        alpha[k + 1] = act.alpha
    alpha = alpha + np.random.default_rng(seed).normal(0.0, noise, n)
    return t, u, alpha


def main(out):
    t, u, alpha = step_record()
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    with open(out, "w", encoding="utf-8") as stream:
        stream.write("time,u,alpha\n")
        for row in zip(t, u, alpha):
            stream.write(",".join(repr(float(v)) for v in row) + "\n")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else
         Path(__file__).parent / "data" / "seed000_step.csv")
