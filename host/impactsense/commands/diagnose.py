"""impactsense diagnose --baseline DATA_REF --data DATA_NEW --json OUT.json [--report DIR]"""

from __future__ import annotations

import sys

ORDER = 50


def register(sub) -> None:
    p = sub.add_parser(
        "diagnose", help="find the physical effect that explains a session's residuals",
        description="Residuals of DATA_NEW against a reference model (calibrated on DATA_REF; the nominal "
                    "physics model when both are the same folder), an effect library (channel_delay, "
                    "sensor_gain, sensor_position, channel_lowpass, wave_speed, damping, anisotropy, "
                    "noise, clipping) and cross-validated forward selection; writes the effects, their "
                    "parameters and the error before and after adding them.")
    p.add_argument("--baseline", required=True, help="reference session folder (or 'bundled')")
    p.add_argument("--data", required=True, help="session folder to explain (the baseline itself for the first loop)")
    p.add_argument("--json", required=True, help="output JSON")
    p.add_argument("--report", default=None, help="folder for plots and summary.md")
    p.set_defaults(func=run)


def _progress(msg):
    if not sys.stderr.isatty():
        return
    print(f"\r  {msg:<60}", end="", file=sys.stderr, flush=True)


def run(args) -> int:
    from ..data import load_session, resolve_session_path
    from ..diagnose import diagnose, write_report

    base = load_session(args.baseline)
    same = resolve_session_path(args.baseline).resolve() == resolve_session_path(args.data).resolve()
    data = base if same else load_session(args.data)
    result, details = diagnose(base, data, progress=_progress, same=same)
    if sys.stderr.isatty():
        print(file=sys.stderr)
    from ..outputs import json_text, write_file

    write_file(args.json, json_text(result))
    if args.report:
        write_report(result, details, args.report)
    print(f"reference: {result['reference']}")
    print(f"{'effect':<16} {'sensor':<7} {'score':>8}  sig  params")
    for e in result["effects"]:
        ps = ", ".join(f"{k}={v:.4g}" for k, v in e["params"].items() if isinstance(v, (int, float)))
        s = "-" if e["sensor"] is None else str(e["sensor"])
        print(f"{e['effect']:<16} {s:<7} {e['score']:8.1f}  {'yes' if e['significant'] else 'no ':<4} {ps}")
    for u in result.get("unabsorbed_channels", []):
        lo, hi = u["param_ci95"].get("offset_mm", [float("nan")] * 2)
        print(f"channel {u['sensor']}: its timing asks for a sensor move of {u['params']['offset_mm']:.0f} mm (95 % "
              f"{lo:.0f}..{hi:.0f}), more than a re-glued disc's {u['max_move_mm']:.0f} mm (a quarter of the nearest "
              f"sensor spacing): not named; a change the models cannot absorb (retrain leaves the channel out: "
              f"three-sensor position and class)")
    b, a = result["before"], result["after"]
    out = [u["sensor"] for u in result.get("unabsorbed_channels", [])]
    if out:
        print(f"before / after over the other channels' timing (channel {', '.join(map(str, out))} left out)")
    print(f"{'':<16} {'before':>10} {'after':>10}")
    for k in ("dtoa_rms_us", "mae_mm", "energy_rms"):
        print(f"{k:<16} {b[k]:10.3f} {a[k]:10.3f}")
    return 0
