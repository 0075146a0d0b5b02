"""impactsense calibrate: fit the FEM twin (plate E, nu; PZT block; damping D_s) to four measured drops."""

from __future__ import annotations

ORDER = 45


def register(sub) -> None:
    p = sub.add_parser(
        "calibrate", help="calibrate the simulator on four measured drops (docs/method.md, Calibration)",
        description="Picks four repeatable drops (or takes --drops), fits plate E and nu on the full factorial "
                    "grid (Eq. 16, fast first-arrival model, FEM-confirmed), D_s from the envelope decay, nu with E and D_s "
                    "from the band group delays (claimed only when the twin explains them), then the "
                    "PZT block by a Sobol design of FEM runs, surrogates and surrogate optimisation. Writes CAL.json "
                    "(its 'sim_params' feed `simulate-dataset --calibration`), per-stage caches and figures "
                    "next to it. Re-running resumes from the caches.")
    p.add_argument("data", help="measured session folder (or 'bundled' for session-1)")
    p.add_argument("--out", required=True, help="calibration JSON to write (CAL.json)")
    p.add_argument("--drops", default="auto",
                   help="'auto' (default) or four comma-separated case ids (case_id column of impacts.csv)")
    p.add_argument("--budget", type=int, default=32, help="FEM runs in the PZT Sobol design (default 32)")
    p.add_argument("--seed", type=int, default=0, help="seed of the Sobol design and the surrogates (default 0)")
    p.add_argument("--workers", type=int, default=2, help="FEM runs in parallel processes (default 2)")
    p.add_argument("--nu-step", type=float, default=0.001,
                   help="nu step of the plate grid (default 0.001; the grid spans the material's priors, "
                        "searched coarse to fine when it exceeds 5,000 points: docs/method.md)")
    p.add_argument("--e-step", type=float, default=250.0, help="E step of the plate grid, MPa (default 250)")
    p.add_argument("--aic-blend", type=float, default=1.0,
                   help="core ToA for Eq. 16: 1 = AIC onset (default, amplitude independent), 0 = threshold")
    p.add_argument("--rig-delay-us", "--channel-delay-us", dest="rig_delay_us", default=None,
                   help="the rig's four per-channel delays in us (default: rig.json's rig_delay_us, else 0)")
    p.add_argument("--surrogate-trials", type=int, default=8, help="hyper-parameter candidates per surrogate")
    p.add_argument("--nu-rounds", type=int, default=2,
                   help="rounds of the nu stage (E, nu, D_s from the band group delays with each drop's position "
                        "fitted; default 2); 0 skips it and keeps the grid's nu and the decay D_s")
    p.add_argument("--support", default="rig", metavar="rig|auto|SUPPORT",
                   help="plate support of the twin: 'rig' (default: rig.json's plate_support text), a support "
                        "(simply_supported, simply_supported_soft, free, clamped, elastic_rim), or "
                        "'auto': the candidate (simply supported, free, clamped, elastic rims of 1e8-1e10 N/m per m) "
                        "whose band group delays fit best, recorded in CAL.json plate.support_choice")
    p.add_argument("--rim-stiffness", type=float, default=None,
                   help="--support elastic_rim: the rim's stiffness on w, N/m per metre of edge")
    p.add_argument("--disc-bond", default="off", metavar="off|fit",
                   help="the discs' bond: 'off' (default: perfectly bonded ceramic, disc_stiffness_scale 1) or 'fit': "
                        "the scale in [0.2, 1] whose band group delays fit best (positions fitted), into sim_params; "
                        "recorded in CAL.json disc_bond")
    p.add_argument("--no-fem", action="store_true",
                   help="the plate grid only (no FEM confirmation, no PZT design; the seed's PZT block is kept)")
    p.add_argument("--plate-only", action="store_true",
                   help="the plate stages only: the grid, a laminate's E1/E2/G12, the FEM's E scan of the four "
                        "drops (no damping, nu, support, bond or PZT design: the seed's PZT block and D_s kept); "
                        "minutes on a new rig")
    p.add_argument("--no-design", action="store_true",
                   help="every stage but the PZT design: the plate, the damping from the envelope decay, nu; the "
                        "seed's PZT block kept (the chain's channel gains and the twin's fingerprint are fitted on "
                        "the calibration drops after training all the same); about a third of a cold calibration")
    p.add_argument("--element-mm", type=float, default=None, help="FEM element size override (coarse mesh)")
    p.add_argument("--max-elements", type=int, default=30_000,
                   help="the twin's mesh: Eq. 1's element size, but at most this many elements on the plate "
                        "(default 30000; 0: no cap); written into CAL.json's sim_params (element_mm) when it "
                        "binds, so the virtual drops and the site map use that mesh too")
    p.add_argument("--twin-span", choices=("measured", "default"), default="measured",
                   help="the twin's simulated span (sim_params duration_ms): measured (default: the calibration drops' "
                        "median n2 after their onset, at least 6 ms, within the record and a memory/CPU bound; "
                        "docs/method.md \"The twin's span\") or default (the simulator's 6 ms)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    from .simulate import add_scheduler_option

    add_scheduler_option(p)
    p.set_defaults(func=run)


def _drops(text: str):
    from ..errors import ConfigError
    if text.strip().lower() == "auto":
        return "auto"
    try:
        ids = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ConfigError(f"--drops must be 'auto' or four comma-separated case ids, got {text!r}") from None
    if len(ids) != 4 or len(set(ids)) != 4:
        raise ConfigError(f"--drops needs four different case ids, got {text!r}")
    return ids


def _at_bounds(cal: dict, lam: dict) -> str:
    """"; at the material's prior bound: ..." naming the constants (a laminate's E1, E2, G12; an isotropic
    plate's E, nu) the fit left on a bound of the materials table's range (the fit wanted beyond it: the rig's
    material or the table's range is off, or the drops cannot tell that constant)."""
    from ..data import load_rig
    from ..errors import DataError
    from ..materials import material_for_rig

    try:
        mat = material_for_rig(load_rig(cal["data"]))
    except (DataError, KeyError, TypeError):
        return ""
    hit = []
    for key, name in (("E1_mpa", "e1_pa"), ("E2_mpa", "e2_pa"), ("G12_mpa", "g12_pa"), ("E_mpa", "e_pa"),
                      ("nu", "nu")):
        prior, v = getattr(mat, name, None), lam.get(key)
        if prior is None or v is None or prior.hi <= prior.lo:
            continue
        scale, unit = (1e6, " MPa") if key.endswith("_mpa") else (1.0, "")
        lo, hi = prior.lo / scale, prior.hi / scale
        if min(abs(v - lo), abs(v - hi)) <= 1e-3 * (hi - lo):
            text = f"{v:.0f}" if scale > 1 else f"{v:.3f}"
            hit.append(f"{key.removesuffix('_mpa')} {text}{unit} ({'lower' if abs(v - lo) < abs(v - hi) else 'upper'})")
    return f"; AT THE MATERIAL'S PRIOR BOUND: {', '.join(hit)}" if hit else ""


def _twin_lines(cal: dict) -> list[str]:
    """The summary's lines on what the twin took from the logger and the decay: gain, span, loss factor."""
    lines = []
    lg = cal.get("logger_gain")
    if lg:
        lines.append(f"logger gain: {lg['skipped']}" if "skipped" in lg else
                     f"logger gain: circuit gain {lg['circuit_gain']:.4g} (x{lg['over_seed']:.3g} the seed's), the "
                     f"calibration drops' median peak {lg['measured_peak_median_counts']:.0f} counts measured, "
                     f"{lg['seed_peak_median_counts']:.0f} at the seed's gain")
    ts = cal.get("twin_span")
    if ts:
        n2 = "-" if ts.get("measured_n2_ms") is None else f"{ts['measured_n2_ms']:.1f}"
        lines.append(f"the twin's span: {ts['duration_ms']:.1f} ms after the touch (the calibration drops' median n2 "
                     f"{n2} ms after their onset; set by: {ts['bound']})")
    tl = cal.get("twin_loss")
    if tl:
        rates = ", ".join("-" if r is None else f"{r:.0f}" for r in tl["rate_per_s"])
        lines.append(f"the twin's loss factor: {tl['loss_factor']:.4g}, D_s {tl['damping_stage_per_s']:.0f} -> "
                     f"{tl['damping_per_s']:.0f} 1/s ({tl['why']}; energy decay per octave band from "
                     f"{tl['bands_hz'][0][0] / 1e3:g} kHz: {rates} 1/s)" if tl["kept"] else
                     f"the twin's loss factor: none ({tl['why']})")
    return lines


def summary(cal: dict) -> str:
    """A short table a person can read."""
    pl = cal["plate"]
    # a laminate's E_mpa is its equivalent isotropic E (below); the grid's own optimum is E_grid_mpa
    e_fast = pl.get("E_fast_mpa", pl.get("E_grid_mpa") if pl.get("laminate") else None) or pl["E_mpa"]
    lines = [f"calibration drops (cases, excluded from every test set): {cal['drops']['case_ids']}",
             f"plate, fast model: E = {e_fast:.0f} MPa, nu = {pl.get('nu_grid', pl['nu']):.3f}; Eq. 16 loss {pl['loss_eq16_us2']:.0f} "
             f"us^2 (rms DToA error {pl['rms_dtoa_error_us']:.1f} us) over {pl['grid']['points']} grid points"
             f"{' (coarse to fine)' if pl['grid'].get('coarse_to_fine') else ''}; "
             f"within 1.25 x min: E {pl['near_optimal']['E_mpa']}, nu {pl['near_optimal']['nu']}"]
    lam = pl.get("laminate")
    if not lam:
        lines[-1] += _at_bounds(cal, {"E_mpa": e_fast, "nu": pl.get("nu_grid", pl["nu"])})
    if lam:
        g = lam["guess"]
        lines.append(f"plate, laminate (fibres at {lam['axis_deg']:.0f} deg): E1 = {lam['E1_mpa']:.0f}, E2 = "
                     f"{lam['E2_mpa']:.0f}, G12 = {lam['G12_mpa']:.0f} MPa (E1/E2 {lam['E1_over_E2']:.2f}, nu12 "
                     f"{lam['nu12']:.2f}); Eq. 16 rms {lam['rms_dtoa_error_us']:.1f} us (the table's shape "
                     f"{lam['rms_dtoa_error_us_typical_shape']:.1f} us); first guess from the picks E1/E2 "
                     f"{g['E1_over_E2']:.2f}" + _at_bounds(cal, lam))
    if "fem_loss_eq16_us2" in pl:
        scan = ", ".join(f"{k}: {v:.0f}" for k, v in pl["fem_scan"].items())
        lines.append(f"plate, FEM twin: E = {pl['E_mpa']:.0f} MPa; Eq. 16 loss {pl['fem_loss_eq16_us2']:.0f} us^2 "
                     f"(rms {pl['fem_rms_dtoa_error_us']:.1f} us); FEM scan E -> loss: {scan}")
    sc = pl.get("support_choice")
    if sc:
        rows = "; ".join(f"{c['label']} {c['chi2_dof']:.0f}" for c in sc["candidates"])
        lines.append(f"plate support from the group delays (chi^2/dof, positions fitted): {rows} -> {sc['chosen']}")
    db = cal.get("disc_bond")
    if db:
        scan = ", ".join(f"{k} {v:.0f}" for k, v in db["chi2_dof"].items())
        lines.append(f"disc bond from the group delays (disc_stiffness_scale -> chi^2/dof, positions fitted): {scan} "
                     f"-> {db['scale']:.3f} (chi^2/dof {db['chi2_dof_bonded']:.0f} bonded, {db['chi2_dof_fit']:.0f} "
                     f"fitted; {db['seconds']:.0f} s)")
    nf = pl.get("nu_fit")
    if nf and nf.get("skipped"):
        lines.append(f"plate, nu: {nf['rule']}; claimed: E = {pl['E_mpa']:.0f} MPa, nu = {pl['nu']:.3f} (the grid's)")
    elif nf:
        verdict = "claimed" if nf["identified"] else "NOT claimed"
        lines.append(f"plate, group delays with positions fitted: nu = {nf['nu']:.3f} +- {nf['sd']['nu']:.3f}, "
                     f"E = {nf['E_mpa']:.0f} MPa, D_s = {nf['damping_per_s']:.0f} 1/s, chi^2/dof {nf['chi2_dof']:.2f} "
                     f"-> {verdict} ({nf['rule']}); positions moved {nf['position_shift_rms_mm']:.1f} mm rms")
        lines.append(f"plate, claimed: E = {pl['E_mpa']:.0f} MPa, nu = {pl['nu']:.3f}")
    dd = cal.get("damping_from_decay")
    if dd:
        lines.append(f"damping from the envelope decay: D_s = {dd['estimate_per_s']:.0f} +- {dd['se_per_s']:.0f} 1/s "
                     f"(per drop {', '.join(f'{v:.0f}' for v in dd['per_drop_per_s'])}; twin's decay moves "
                     f"{dd['slope_decay_per_damping']:.2f} per unit D_s, theory 0.5)")
    pd = cal.get("pzt_damping", {})
    if "f2" in pd:
        f = cal["fitted"]
        lines.append(f"PZT/damping ({pd['chosen']}; {pd['budget']} FEM runs): D_s = {f['damping_per_s']:.0f} 1/s, "
                     f"d31 = {f['pzt_d31_pc_n']:.0f} pC/N, eps33 = {f['pzt_eps33_rel']:.0f}, E11 = "
                     f"{f['pzt_e11_mpa']:.0f} MPa; f2_rel = {pd['f2_rel']:.3g}, f3 = {pd['f3']:.3g}")
        lines.append(f"{'surrogate test R2':26s}" + "".join(f"{k:>8s}" for k in ("RF", "GPR", "NN", "SVD")))
        for out, row in pd["surrogate_r2_test"].items():
            lines.append(f"{out:26s}" + "".join(f"{row[k]['r2_test']:8.2f}" for k in ("RF", "GPR", "NN", "SVD")))
        for out, rows in pd["screening"].items():
            sig = [r["term"].replace("pzt_", "") for r in rows if r["significant"]][:5]
            lines.append(f"screening, {out}: {', '.join(sig) if sig else 'no significant term'}")
    else:
        lines.append(f"PZT/damping: {pd.get('skipped', '-')}")
    lines += _twin_lines(cal)
    lines.append("wall time [s], this run: " + ", ".join(f"{k} {v:.1f}" for k, v in cal["wall_time_s"].items()))
    if "stage_compute_time_s" in cal:
        lines.append("compute time [s] per stage (cached stages: when last computed): "
                     + ", ".join(f"{k} {v:.1f}" for k, v in cal["stage_compute_time_s"].items()))
    return "\n".join(lines)


def run(args) -> int:
    from ..calibration.pipeline import CalibrateOptions, calibrate
    from ..errors import ConfigError

    data = args.data
    if data == "bundled":
        from importlib import resources
        data = str(resources.files("impactsense") / "data" / "session-1")
    delays = None
    if args.rig_delay_us:
        try:
            delays = [float(v) for v in args.rig_delay_us.split(",")]
        except ValueError:
            raise ConfigError(f"--rig-delay-us needs four numbers, got {args.rig_delay_us!r}") from None
    opts = CalibrateOptions(drops=_drops(args.drops), budget=args.budget, seed=args.seed, workers=args.workers,
                            progress=not args.quiet, nu_step=args.nu_step, e_step_mpa=args.e_step,
                            aic_blend=args.aic_blend, rig_delay_us=delays,
                            surrogate_trials=args.surrogate_trials, fem=not args.no_fem,
                            nu_rounds=args.nu_rounds, support=args.support,
                            rim_stiffness_n_m2=args.rim_stiffness, disc_bond=args.disc_bond,
                            max_elements=args.max_elements or None, plate_only=args.plate_only,
                            design=not args.no_design, twin_span=args.twin_span)
    simulate = None
    if opts.fem and args.element_mm is not None:
        from ..calibration.fem import fem_simulator
        simulate = fem_simulator(args.workers, element_mm=float(args.element_mm))
    cal = calibrate(data, args.out, opts, simulate=simulate)
    print(summary(cal))
    print(f"wrote {args.out}")
    return 0
