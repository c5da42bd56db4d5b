"""`simecs bench model`: the standard case, its real-time factor, its cost per part and its error.

Standard case: the Spider, all 7 joints, from q = 0 at rest to `spider.STANDARD_TARGET` at 100 % speed
and 100 % acceleration, 5 s simulated, full drive fidelity (default parameters), output every 10 ms.
Error: max over joints and output samples of |q - q_ref_run| against the same run at a 10x finer
mechanics step (and so 10x finer drive substeps).
"""

from __future__ import annotations

import json
import os
import time

import numpy as np

STOP = 5.0
OUT = 0.01


def run_case(step: float | None = None, model: str = "spider", values: dict | None = None, substeps=None):
    from . import get_model

    pkg = get_model(model)
    sim = pkg.build(values or {})
    sim.set_initial([0.0] * sim.n)
    sim.set_joint_path([(list(pkg.spec.standard_target), 100.0, 100.0)])
    sim.start(STOP, OUT, step, substeps)
    t0 = time.perf_counter()
    rows = [sim.advance(0.0)]
    while not sim.finished:
        rows.append(sim.advance(sim.time + 0.02))
    wall = time.perf_counter() - t0
    data = np.vstack(rows)
    timing = dict(sim.timing)
    cols = list(sim.columns)
    sim.close()
    return data, cols, wall, timing


def run_model_bench(json_out: bool = False, model: str = "spider") -> dict:
    from . import get_model, warmup

    t_warm = warmup()
    pkg = get_model(model)
    step = pkg.spec.default_step
    # best of two timed runs: the machine is shared
    best = None
    for _ in range(2):
        data, cols, wall, timing = run_case(step, model)
        if best is None or wall < best[2]:
            best = (data, cols, wall, timing)
    data, cols, wall, timing = best
    ref, _, wall_ref, _ = run_case(step / 10.0, model)
    n = pkg.n
    qi = [cols.index(f"joint{j}.q") for j in range(1, n + 1)]
    err = np.abs(data[:, qi] - ref[:, qi])
    per_joint = err.max(axis=0)
    drive = timing["drive"]
    output = timing["output"]
    mech = max(wall - drive - output, 0.0)
    res = {
        "model": model,
        "case": f"{model}: q=0 -> {list(pkg.spec.standard_target)} at 100%/100%, {STOP:g} s, "
        f"output {OUT * 1e3:g} ms",
        "step_ms": step * 1e3,
        "drive_substeps": pkg.spec.substeps,
        "sim_time_s": STOP,
        "wall_s": round(wall, 4),
        "rtf": round(STOP / wall, 2),
        "cost_s_per_sim_s": {
            "mechanics_exudyn": round(mech / STOP, 5),
            "drive_numba_prestep": round(drive / STOP, 5),
            "output_rows": round(output / STOP, 5),
        },
        "max_joint_error_mrad": round(float(per_joint.max()) * 1e3, 4),
        "joint_error_mrad": [round(float(e) * 1e3, 4) for e in per_joint],
        "reference_step_ms": step * 1e2,
        "reference_wall_s": round(wall_ref, 2),
        "warmup_s": round(t_warm, 2),
        "cores_used": 1,
        "cpu_count": os.cpu_count(),
        "target": {"rtf_min": 10, "max_joint_error_mrad_max": 1.0},
    }
    res["pass"] = bool(res["rtf"] >= 10 and res["max_joint_error_mrad"] <= 1.0)
    print(f"model bench: {res['case']}")
    print(f"  mechanics step {res['step_ms']:g} ms, drive substeps {res['drive_substeps']} (RK4)")
    print(f"  {'real-time factor (1 core)':34s} {res['rtf']:8.2f}   (target >= 10)")
    print(f"  {'wall time for 5 s simulated':34s} {res['wall_s']:8.3f} s")
    for k, v in res["cost_s_per_sim_s"].items():
        print(f"  {'cost ' + k:34s} {v * 1e3:8.1f} ms per simulated s")
    print(
        f"  {'max joint error vs 10x finer step':34s} {res['max_joint_error_mrad']:8.4f} mrad (target <= 1)"
    )
    print("  per joint (mrad): " + " ".join(f"{e:.4f}" for e in res["joint_error_mrad"]))
    print(f"  reference run wall time {res['reference_wall_s']} s; warm-up {res['warmup_s']} s")
    print(f"  {'PASS' if res['pass'] else 'FAIL'}")
    if json_out:
        print(json.dumps(res))
    return res
