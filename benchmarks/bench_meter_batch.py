"""CPU of the safety meter on the batched engine (issue 15, P7): ``SafetyMeter.observe_batch`` per control step.

The study's arm and envelope (``dmc/reacher-easy``, its ``safety.yaml``: the wrist's limit, the effort ratio, the
finger body's speed), ``--worlds`` worlds in one :class:`~sim2real.batched.BatchedEnv` (the study steps 128) driven
by the scripted ``ReacherPD`` baseline for ``--episodes`` episodes of 1000 steps. Only the meter is timed
(``time.perf_counter`` around every ``observe_batch`` call and the ``episodes`` read that ends an episode), in
microseconds per control step of the whole batch; the physics and the policy run between the timed calls, so the
meter reads the batch as it does in an evaluation (the stepped worlds' memory, not a hot cache). The last line
prints a hash of the measured quantities: two checkouts that measure the same peaks and counts print the same.
Compare a start commit by running this script with ``PYTHONPATH`` set to a ``git archive`` of it::

    MUJOCO_GL=egl nice -n 10 .venv/bin/python benchmarks/bench_meter_batch.py
    MUJOCO_GL=egl PYTHONPATH=/tmp/before nice -n 10 .venv/bin/python benchmarks/bench_meter_batch.py
"""

from __future__ import annotations

import argparse
import hashlib
import os
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", type=int, default=128)
    parser.add_argument("--episodes", type=int, default=3)
    args = parser.parse_args()

    import sim2real
    from sim2real.agents import baseline_for
    from sim2real.batched import BatchedEnv
    from sim2real.safety import load_limits

    task, n = "dmc/reacher-easy", args.worlds
    limits = load_limits(Path(sim2real.__file__).parent / "data/study/dmc-reacher-easy/safety.yaml")
    worlds = BatchedEnv(task, n, (), seed=0)
    meter = limits.meter(worlds.models[0], n)
    meter.bind_batch(worlds.physics.batch)
    policy = baseline_for(task)
    everyone = np.arange(n)  # the sorted indices every version takes (the lockstep loop now passes None)
    seconds, steps, measured = 0.0, 0, []
    for e in range(args.episodes):
        obs, _ = worlds.reset(seed=list(range(e * n, (e + 1) * n)))
        meter.reset()
        for _ in range(1000):
            obs, *_ = worlds.step(np.asarray(policy(obs)))
            clock = time.perf_counter()
            meter.observe_batch(everyone, worlds.models, worlds.physics.data)
            seconds += time.perf_counter() - clock
            steps += 1
        clock = time.perf_counter()
        measured.append(meter.episodes(np.zeros(n, bool)))
        seconds += time.perf_counter() - clock
    worlds.close()
    digest = hashlib.sha256(b"".join(v.tobytes() for m in measured for v in m.values())).hexdigest()[:16]
    print(f"# {sim2real.__file__}")
    print(f"RESULT observe_batch {seconds / steps * 1e6:.1f} us per step of {n} worlds ({steps} steps)  "
          f"quantities sha256 {digest}")  # fmt: skip


if __name__ == "__main__":
    main()
