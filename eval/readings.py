"""The results in words: ``summary.md`` of `vislam bench` (per drive the model line, readings in
a few sentences, the table of figures and the drive-fitted RPE per segment length) and
``score.md`` of `vislam score`; report.html shows the same text (:mod:`eval.report`).
"""

from __future__ import annotations

import math

from vislam.ekf.model import ar1_coefficient, long_run_pixel_sigma
from vislam.eval.consistency import POSE_NEES_BAND, reference_honesty
from vislam.eval.inertial_truth import AGREEMENT_RATIO, GyroAgreement
from vislam.eval.metrics import ALIGN_DESCRIPTIONS
from vislam.eval.rpe_segments import RPE_END_TOLERANCE, lengths_text


def format_figure(x, digits=2) -> str:
    """A table cell: "–" for no value; floats fixed-point, or as 2.0e10 / 3.5e-05 when that
    would print a long number (at least 1e5) or only zeros (below 10^-digits)."""
    if x is None:
        return "–"
    if isinstance(x, float):
        if x != 0 and math.isfinite(x) and not 10.0**-digits <= abs(x) < 1e5:
            mantissa, exponent = f"{x:.1e}".split("e")
            return f"{mantissa}e{int(exponent)}"
        return f"{x:.{digits}f}"
    return str(x)


def format_small(x) -> str:
    """A table cell for figures that are often well below 1 (the RPE's °/m: 0.065, 0.0021):
    two significant digits and at least two decimals (2.62, 0.10, 0.0021); "–" for no value,
    and as :func:`format_figure` below 1e-4 or from 1e5 on."""
    if x is None or not isinstance(x, float) or not math.isfinite(x) or x == 0:
        return format_figure(x)
    if not 1e-4 <= abs(x) < 1e5:
        return format_figure(x)
    return f"{x:.{max(2, 1 - math.floor(math.log10(abs(x))))}f}"


#: The columns of a drive's table in summary.md: (header, key in the row or in its
#: "vs_smoother" part, digits: decimals, or a formatter such as :func:`format_small`). A
#: column with no value on any row of the drive is left out.
SUMMARY_COLUMNS = (
    ("time (s)", "runtime_s", 2), ("frames/s", "frames_per_s", 1), ("ATE (m)", "ate_m", 2),
    ("ATE al. (m)", "ate_aligned_m", 2), ("t_rel (%)", "rpe_trans_pct", 2),
    ("r_rel (°/100m)", "rpe_rot_deg_per_100m", 2), ("RPE (%)", "rpe_drive_trans_pct", 2),
    ("RPE (°/m)", "rpe_drive_rot_deg_per_m", format_small), ("NEES", "nees_pose_mean", 2),
    ("map RMSE (m)", "map_rmse_m", 2), ("lm NEES", "nees_landmark_mean", 2),
    ("vs sm. ATE al. (m)", "vs_smoother.ate_aligned_m", 2), ("vs sm. map (m)", "vs_smoother.map_rmse_m", 2),
    ("vs sm. NEES", "vs_smoother.nees_pose_mean", 2), ("vs sm. in 95%", "vs_smoother.inside_95_fraction", 2),
)


def cell(row: dict, key: str):
    """The value of column ``key`` (:data:`SUMMARY_COLUMNS`) in an estimator's row."""
    if key.startswith("vs_smoother."):
        return (row.get("vs_smoother") or {}).get(key.split(".", 1)[1])
    return row.get(key)


def summary_markdown(results: dict) -> str:
    """The results as Markdown: per sequence the model line, readings in words
    (:func:`readings`), and a table of the columns that have a value on some row."""
    lines = ["# vislam benchmark", ""]
    lines.append(f"t_rel, r_rel: {results['rpe_definition']}.")
    if results.get("rpe_drive_definition"):
        lines.append(f"RPE: {results['rpe_drive_definition']}.")
    align = _alignment_words(results)
    lines.append(f"ATE al.: the ATE after {align}.")
    lines.append("vs smoother: the estimator against the smoother's estimate on the same data "
                 f"(ATE after {align}; map RMSE over tracks both estimated; pose NEES of "
                 "the difference under the estimator's own covariance, and the share of steps "
                 "inside chi2.ppf(0.95, 6)).")
    lines.append("")
    for s in results["sequences"]:
        gt = "ground truth" if s["has_ground_truth"] else "no ground truth"
        lines.append(f"## {s['name']} ({s['frames']} frames, {gt})")
        lines.append("")
        said_model = model_line(s.get("model"))
        if said_model:
            lines += [said_model, ""]
        said = readings(s)
        if said:
            lines += [f"- {sentence}" for sentence in said] + [""]
        header, rows = sequence_table(s)
        lines.append("| " + " | ".join(header) + " |")
        lines.append("|" + "|".join(["---"] * len(header)) + "|")
        lines += ["| " + " | ".join(cells).rstrip() + " |" for cells in rows]
        lines.append("")
        per_length = rpe_length_table(s)
        if per_length is not None:
            caption, header, rows = per_length
            lines += [caption, ""]
            lines.append("| " + " | ".join(header) + " |")
            lines.append("|" + "|".join(["---"] * len(header)) + "|")
            lines += ["| " + " | ".join(cells).rstrip() + " |" for cells in rows]
            lines.append("")
    return "\n".join(lines)


def drive_rpe_of(s: dict) -> dict | None:
    """The drive-fitted RPE detail (results.json's ``rpe_drive``) of the drive's first
    estimator that has one: its lengths and note are the truth's, the same for every
    estimator."""
    return next((r["rpe_drive"] for r in s["estimators"]
                 if not r["error"] and r.get("rpe_drive") is not None), None)


def rpe_sentence(s: dict) -> str | None:
    """Which segment lengths the drive's RPE used and why (or, in words, why it has none);
    None for a drive without ground truth or without a scored estimator."""
    fitted = drive_rpe_of(s)
    if fitted is None:
        return None
    kitti = any(r.get("rpe_trans_pct") is not None for r in s["estimators"] if not r["error"])
    path = fitted.get("path_length_m")
    path_words = (" true path" if path is None
                  else f" {format_figure(float(path), 1)} m true path")
    if fitted.get("note"):
        return f"No RPE: {fitted['note']}."
    lengths = fitted.get("lengths_m") or []
    sentence = (f"RPE over segments of {lengths_text(lengths)} (chosen from the drive's"
                f"{path_words}; {fitted.get('n_segments', 0)} segments per estimator)")
    empty = [float(e["length_m"]) for e in fitted.get("per_length") or []
             if not e.get("n_segments")]
    if empty:
        sentence += (f"; no segment of {lengths_text(empty)} had an end within "
                     f"{100 * RPE_END_TOLERANCE:g} % of its length")
    if kitti:
        sentence += "; KITTI's t_rel / r_rel over 100-800 m as well"
    else:
        sentence += "; KITTI's 100-800 m segments do not fit this drive"
    return sentence + "."


def rpe_length_table(s: dict) -> tuple[str, list[str], list[list[str]]] | None:
    """The drive-fitted RPE per segment length: a caption, the header (a column per length,
    with its number of segments) and per scored estimator the mean translation error (% of the
    segment) / rotation error (°/m); None when the drive has no such figure."""
    fitted = drive_rpe_of(s)
    if fitted is None or not fitted.get("n_segments"):
        return None
    lengths = [e for e in fitted.get("per_length") or [] if e.get("n_segments")]
    header = ["estimator"] + [f"{float(e['length_m']):g} m ({e['n_segments']})" for e in lengths]
    rows = []
    for r in s["estimators"]:
        if r["error"] or r.get("rpe_drive") is None:
            continue
        by = {float(e["length_m"]): e for e in r["rpe_drive"].get("per_length") or []}
        cells = [r["name"]]
        for e in lengths:
            mine = by.get(float(e["length_m"])) or {}
            t = (mine.get("trans_pct") or {}).get("mean")
            rot = (mine.get("rot_deg_per_m") or {}).get("mean")
            cells.append(f"{format_figure(t, 2)} / {format_small(rot)}")
        rows.append(cells)
    caption = ("RPE per segment length (its number of segments in brackets): mean translation "
               "error in % / mean rotation error in °/m of the segment's true path; results.json "
               "holds the median and RMSE too, and the errors in m and deg.")
    return caption, header, rows


def _alignment_words(results: dict) -> str:
    """The alignment of the results' aligned ATEs in words (SE(3) when not recorded); where the
    drives differ (raw-IMU drives are aligned in yaw by default), each mode with its drives."""
    default = results.get("alignment") or "se3"
    modes: dict[str, list[str]] = {}
    for s in results.get("sequences", []):
        modes.setdefault(s.get("alignment") or default, []).append(s["name"])
    if len(modes) <= 1:
        mode = next(iter(modes), default)
        return ALIGN_DESCRIPTIONS.get(mode, f"{mode} alignment")
    return "; ".join(f"{ALIGN_DESCRIPTIONS.get(m, m)} on {', '.join(names)}"
                     for m, names in modes.items())


def sequence_table(s: dict) -> tuple[list[str], list[list[str]]]:
    """A drive's table as text cells: the header and one row per estimator, with the columns
    of :data:`SUMMARY_COLUMNS` that have a value on some row (a failed estimator: its error)."""
    ok = [r for r in s["estimators"] if not r["error"]]
    columns = [c for c in SUMMARY_COLUMNS if any(cell(r, c[1]) is not None for r in ok)]
    rows = []
    for r in s["estimators"]:
        if r["error"]:
            rows.append([r["name"], f"failed: {r['error']}"] + [""] * max(len(columns) - 1, 0))
        else:
            rows.append([r["name"]] + [digits(cell(r, key)) if callable(digits)
                                       else format_figure(cell(r, key), digits)
                                       for _, key, digits in columns])
    return ["estimator"] + [c[0] for c in columns], rows


def _names(rows: list[tuple[str, float]]) -> str:
    return ", ".join(f"{name} ({format_figure(value, 1)})" for name, value in rows)


def readings(s: dict) -> list[str]:
    """A drive's results in a few sentences: the most accurate estimator, which are consistent
    and which over- or underconfident against ground truth (mean pose NEES against the band of
    one 6-dof NEES, :data:`eval.consistency.POSE_NEES_BAND`) and against the smoother, and the
    warning when the reference itself is not consistent (:func:`eval.consistency.reference_honesty`)."""
    ok = [r for r in s["estimators"] if not r["error"]]
    out = []
    failed = [r["name"] for r in s["estimators"] if r["error"]]
    if failed:
        out.append(f"Failed: {', '.join(failed)} (see results.json).")
    scored = [r for r in ok if r.get("ate_aligned_m") is not None]
    if scored:
        best = min(scored, key=lambda r: r["ate_aligned_m"])
        drift = ""
        if best.get("rpe_trans_pct") is not None:
            drift = f", t_rel {format_figure(best['rpe_trans_pct'])} %"
        elif best.get("rpe_drive_trans_pct") is not None:
            drift = f", RPE {format_figure(best['rpe_drive_trans_pct'])} %"
        sentence = f"Most accurate: {best['name']} (aligned ATE {format_figure(best['ate_aligned_m'])} m{drift})"
        ekfs = [r for r in scored if r["name"].startswith("ekf-")]
        if ekfs and not best["name"].startswith("ekf-"):
            e = min(ekfs, key=lambda r: r["ate_aligned_m"])
            sentence += f"; the best EKF is {e['name']} ({format_figure(e['ate_aligned_m'])} m)"
        out.append(sentence + ".")
    else:
        near = [r for r in ok if cell(r, "vs_smoother.ate_aligned_m") is not None]
        if near:
            e = min(near, key=lambda r: cell(r, "vs_smoother.ate_aligned_m"))
            out.append(f"No ground truth: the estimator closest to the smoother is {e['name']} "
                       f"(aligned ATE against it {format_figure(cell(e, 'vs_smoother.ate_aligned_m'))} m).")
    said_rpe = rpe_sentence(s)
    if said_rpe:
        out.append(said_rpe)
    lo, hi = POSE_NEES_BAND
    for what, key in (("against ground truth", "nees_pose_mean"),
                      ("against the smoother", "vs_smoother.nees_pose_mean")):
        rows = [(r["name"], cell(r, key)) for r in ok if cell(r, key) is not None]
        if not rows:
            continue
        inside = [x for x in rows if lo <= x[1] <= hi]
        above = [x for x in rows if x[1] > hi]
        below = [x for x in rows if x[1] < lo]
        parts = []
        if inside:
            parts.append(f"consistent: {_names(inside)}")
        if above:
            parts.append(f"overconfident: {_names(above)}")
        if below:
            parts.append(f"underconfident: {_names(below)}")
        out.append(f"Pose NEES {what} (band [{lo:.2f}, {hi:.2f}] for the mean of one drive): "
                   + "; ".join(parts) + ".")
        if key == "nees_pose_mean" and truth_turns_away(s.get("truth_check")):
            out.append(truth_check_sentence(s["truth_check"]))
    out += [x for x in _reference_honesty(s) if x]
    return out


def truth_turns_away(check: dict | None) -> bool:
    """The raw-IMU truth disagrees with the gyro by more than :data:`AGREEMENT_RATIO` times
    what the data sheet allows (:func:`eval.inertial_truth.gyro_agreement`)."""
    return bool(check) and check.get("ratio") is not None and check["ratio"] > AGREEMENT_RATIO


def truth_check_sentence(check: dict) -> str:
    """In words: how far the ground truth's turn departs from the gyro's, and what that means
    for a pose NEES against it."""
    words = GyroAgreement.from_dict(check).words()
    return (f"{words[0].upper()}{words[1:]}: a pose NEES against this truth also counts the "
            "truth's own rotation error, and overstates the estimators' own by an amount not "
            "known here.")


def _reference_honesty(s: dict) -> list[str]:
    """A sentence when the reference smoother's pose NEES against ground truth is outside its
    band (eval.consistency.reference_honesty): its covariance is then not a fair yardstick for
    the EKFs' (vs sm. NEES)."""
    ref = s.get("reference_smoother")
    row = next((r for r in s["estimators"] if r["name"] == ref and not r["error"]), None)
    sentence = None if row is None else reference_honesty(ref, row["nees_pose_mean"])
    return [] if sentence is None else [f"{sentence} (the vs sm. NEES columns).", ""]


def model_line(model: dict | None) -> str:
    """One line on the model the estimators ran under (results.json's ``model``)."""
    if not model:
        return ""
    mode = model.get("mode")
    if mode == "as-given":
        failed = model.get("identification_failed")
        why = f" (identification failed: {failed})" if failed else ""
        return f"Model: the file's extrinsic and the settings as given{why}."
    m = model.get("model") or {}
    v = ", ".join(f"{x:.3g}" for x in m.get("velocity_sigma") or [])
    g = ", ".join(f"{x:.3g}" for x in m.get("gyro_sigma") or [])
    bias = "no gyro bias" if m.get("gyro_bias") is None else "gyro bias " + ", ".join(
        f"{x:.2g}" for x in m["gyro_bias"])
    how = {"identified": "identified from the data" + (" (cached)" if model.get("cached") else ""),
           "config": "from " + str(model.get("source", "--config"))}.get(mode, str(mode))
    radial = "" if m.get("radial_k1") is None else f", radial lens term k1 {m['radial_k1']:.3g}"
    tau = m.get("pixel_correlation_time")
    long_run = long_run_pixel_sigma(m.get('pixel_sigma', float('nan')), tau)
    correlated = "" if tau is None else (
        f" correlated along tracks over {tau:.3g} frames (the estimators use {long_run:.3g} px)"
        if model.get("pixel_reading") != "ar1" else
        f" correlated along tracks over {tau:.3g} frames (ekf-joint reads them as AR(1), a "
        f"{ar1_coefficient(tau):.3g}; the other estimators use {long_run:.3g} px)")
    slow = {what: times for what, times in (("velocity", m.get("velocity_correlation_time")),
                                            ("gyro", m.get("gyro_correlation_time"))) if times}
    drifting = "" if not slow else (
        f", {' and '.join(slow)} errors correlated in time (long-run / white variance "
        + "; ".join(f"{what} {', '.join(f'{x:.3g}' for x in times)}" for what, times in slow.items())
        + ": the estimators use the long-run sigmas)")
    text = (f"Model {how}: velocity sigma {v} m/s, gyro sigma {g} rad/s{drifting}, pixel sigma "
            f"{m.get('pixel_sigma', float('nan')):.3g} px{correlated}, pairing "
            f"{m.get('velocity_pairing')}, "
            f"{bias}{radial}")
    ident = model.get("identification") or {}
    window, n = ident.get("frames"), ident.get("n_frames")
    if window and n and list(window) != [0, n]:
        text += (f"; identified on frames {window[0]}-{window[1] - 1} of {n} (the drive's central "
                 f"{window[1] - window[0]}: `vislam calibrate --max-frames 0` reads every frame)")
    if ident.get("returning_tracks_split"):
        text += (f"; {ident['returning_tracks_split']} returning tracks identified as new "
                 "landmarks (the estimators keep each as one)")
    drift = ident.get("drift_test") or {}
    if drift.get("widening", 1.0) > 1.0:
        text += (f"; every noise level widened {drift['widening']:.2f}x: over stretches of "
                 f"{drift['stretch_s']:g} s, dead reckoning and the smoother disagreed "
                 f"{drift['widening']:.2f}x beyond what the identified model claimed (chi2/dof "
                 f"{drift['ratio']:.2f} on {drift['dof']} dof): the model did not explain the drive")
    elif drift:
        text += (f"; drift check: dead reckoning and the smoother agree over stretches of "
                 f"{drift['stretch_s']:g} s within what the model claims (chi2/dof "
                 f"{drift['ratio']:.2f})")
    test = ident.get("extrinsic_test") or {}
    if test:
        against = (f" against {test['threshold']:.3g}, {test.get('criterion', 'chi-square')}"
                   if "threshold" in test else "")
        oos = test.get("out_of_sample") or {}
        held = ("" if not oos else f"; out-of-sample gain {oos['gain']:.3g} over "
                f"{oos['folds']} held-out stretches")
        text += (f"; extrinsic: {test['decision']} (Wald statistic {test['statistic']:.3g} on "
                 f"{test['dof']} dof{against}{held})")
    arm = model.get("lever_arm") or {}
    if arm.get("ground_truth") is not None:
        model_p, truth_p, truth_s = (" ".join(f"{x:.2f}" for x in arm[k])
                                     for k in ("model", "ground_truth", "ground_truth_sigma"))
        text += (f"; lever arm x y z {model_p} m, the ground truth's {truth_p} +- {truth_s} m "
                 "(from the velocities against the true camera motion, no vision)")
    return text + "."


def score_markdown(result: dict) -> str:
    """The score as Markdown: what was scored and how, then the benchmark's summary of the
    drive (:func:`summary_markdown`: readings and the table of figures); ``result`` the
    score.json content (:func:`eval.score.score`)."""
    traj, a, cov = result["trajectory"], result["association"], result["covariance"]
    if a["by"] == "index":
        how = "by index (no times in the file)"
    else:
        how = (f"by time (|dt| <= {a['t_max_diff_s']:g} s after --t-offset {a['t_offset_s']:g} s; "
               f"largest |dt| {a['max_abs_diff_s']:.3g} s)")
    lines = [
        "# vislam score", "",
        (f"Trajectory: {traj['path']} ({traj['format']}, {traj['poses']} poses); data: "
         f"{result['data']['path'] or result['data']['name']} ({result['data']['frames']} frames)."),
        f"Association: {a['associated_frames']} of {a['trajectory_poses']} poses on frames "
        f"{a['first_frame']}-{a['last_frame']} {how}; only these frames are scored"
        + (f" ({a['unmatched_poses']} poses matched no frame)" if a["unmatched_poses"] else "")
        + (f" ({a['duplicate_poses']} poses on a frame taken by a nearer one)"
           if a["duplicate_poses"] else "") + ".",
    ]
    if cov is None:
        lines.append(f"Covariance: none; {result['nees']}.")
    else:
        lines.append(f"Covariance: {cov['path']} ({cov['kind']}), for "
                     f"{cov['frames_with_covariance']} of the {a['associated_frames']} scored frames.")
    ref = result["reference"]
    if ref is None:
        lines.append("Reference: not run (--no-reference); the vs-smoother figures are null.")
    else:
        lines.append(f"Reference: the batch smoother as vislam bench runs it "
                     f"({' then '.join(ref['estimators_run'])}); its own row is scored on the "
                     "same frames.")
    from vislam.eval.bench_scores import RPE_DRIVE_DEFINITION

    body = summary_markdown({"rpe_definition": result["rpe_definition"],
                             "rpe_drive_definition": result.get("rpe_drive_definition",
                                                                RPE_DRIVE_DEFINITION),
                             "alignment": result["alignment"],
                             "sequences": [result["sequence"]]})
    body_lines = body.splitlines()
    if body_lines and body_lines[0].startswith("# "):
        body_lines = body_lines[1:]
    return "\n".join(lines + body_lines).rstrip() + "\n"
