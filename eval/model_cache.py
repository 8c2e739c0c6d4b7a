"""The identified model of a drive, computed once per drive and kept (``vislam bench``'s default).

``vislam bench`` runs every estimator under the model the data supports
(:func:`graph.identification.identify_model`: noise levels, gyro bias, velocity pairing,
camera-IMU extrinsic). Identification costs tens of seconds to minutes on a real drive, so its
result is cached by the drive's content: the SHA-256 of every array the estimators read
(time stamps, velocities, observations, calibration) and of everything that changes the
answer (the starting filter settings, the smoother's settings, the pairings compared and
:data:`IDENTIFICATION_VERSION`). A second run on the same drive reads the model back; a renamed
or copied file hits the same entry, an edited one does not.

The cache folder is ``$VISLAM_CACHE_DIR``, else ``$XDG_CACHE_HOME/vislam/models``, else
``~/.cache/vislam/models``. Each entry is ``<key>.toml`` (the model, readable by every
command's ``--config``) and ``<key>.json`` (what the identification reported). Entries are
written atomically; an entry that cannot be read (damaged, from another version) is ignored,
logged and replaced; a cache folder that cannot be written is logged and the model is used
without being kept.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from vislam.ekf.config import FilterConfig
from vislam.ekf.errors import InputError
from vislam.ekf.model import Model
from vislam.ekf.sequence import Sequence
from vislam.graph.settings import SmootherSettings

log = logging.getLogger(__name__)

#: Changes whenever the identification would give a different answer on the same input, to a
#: value never used before (so that no old cache entry can match it).
IDENTIFICATION_VERSION = "2026-12-04.38b-lever-arm-excitation-report"


@dataclass
class IdentifiedModel:
    """A drive's identified model and what the identification reported."""

    model: Model
    report: dict  # JSON-able: sigmas' standard deviations, bias test, pairing scores, seconds
    cached: bool  # read from the cache (no identification ran)
    key: str
    path: Path | None  # the cache entry's model file, None when it could not be written


def cache_dir() -> Path:
    """The cache folder (module docstring); not created here."""
    env = os.environ.get("VISLAM_CACHE_DIR")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg else Path.home() / ".cache"
    return base / "vislam" / "models"


def sequence_digest(seq: Sequence) -> str:
    """SHA-256 of every array of ``seq`` an estimator reads (not its name or path)."""
    h = hashlib.sha256()
    c = seq.calibration
    for a in (seq.timestamps, seq.linear_velocity, seq.angular_velocity, seq.obs.frame_ptr,
              seq.obs.track, seq.obs.z, c.K, np.asarray(c.baseline, dtype=float), c.cam_T_imu,
              np.asarray(seq.n_tracks)):
        a = np.ascontiguousarray(a)
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    return h.hexdigest()


#: Smoother settings identification overrides (it solves every round to its EM tolerance), so
#: they do not make another model: left out of the key (cached models stay valid).
IGNORED_SETTINGS = ("rejection_relative_error_tol",)


def cache_key(seq: Sequence, config: FilterConfig, settings: SmootherSettings,
              pairings: tuple[str, ...]) -> str:
    """The entry of ``seq`` identified from ``config`` with the smoother's ``settings`` (less
    the ones identification does not read: :data:`IGNORED_SETTINGS`)."""
    smoother = {k: v for k, v in settings.to_dict().items() if k not in IGNORED_SETTINGS}
    h = hashlib.sha256()
    h.update(sequence_digest(seq).encode())
    h.update(json.dumps({"config": config.to_dict(), "smoother": smoother,
                         "pairings": list(pairings), "version": IDENTIFICATION_VERSION},
                        sort_keys=True, default=str).encode())
    return h.hexdigest()[:32]


def fit_report(fit) -> dict:
    """What :class:`graph.identification.ModelFit` reported, JSON-able."""
    def lst(x):
        return None if x is None else [float(v) for v in np.ravel(x)]

    sigma = fit.cam_T_imu_sigma
    return {
        "velocity_sigma_std": lst(fit.velocity_sigma_std),
        "gyro_sigma_std": lst(fit.gyro_sigma_std),
        "pixel_sigma_std": float(fit.pixel_sigma_std),
        "gyro_bias_std": lst(fit.gyro_bias_std),
        "cam_T_imu_sigma": None if sigma is None else [float(v) if np.isfinite(v) else None
                                                       for v in sigma],
        "cam_T_imu_undetermined": list(fit.cam_T_imu_undetermined),
        "extrinsic_test": dict(fit.extrinsic_test),
        "bias_test": dict(fit.bias_test),
        "radial_k1_std": None if fit.radial_k1_std is None else float(fit.radial_k1_std),
        "radial_test": dict(fit.radial_test),
        "pixel_correlation_test": dict(fit.pixel_correlation_test),
        "motion_correlation_test": dict(fit.motion_correlation_test),
        "pairing_scores": dict(fit.pairing_scores),
        "em_steps": int(fit.iterations),
        "converged": bool(fit.converged),
        "seconds": float(fit.seconds),
        "returning_tracks_split": int(fit.returning_tracks_split),
        "frames": [int(f) for f in fit.frames],
        "n_frames": int(fit.n_frames),
        "drift_test": dict(fit.drift_test),
        "noise_widening": float(fit.noise_widening),
    }


def _read(key: str, folder: Path) -> tuple[Model, dict] | None:
    model_file, report_file = folder / f"{key}.toml", folder / f"{key}.json"
    if not model_file.is_file():
        return None
    try:
        model = Model.from_toml(model_file)
        report = json.loads(report_file.read_text(encoding="utf-8"))
        if not isinstance(report, dict):
            raise ValueError("not a JSON object")
    except (InputError, OSError, ValueError) as exc:
        log.warning("model cache: ignoring %s (%s); identifying again", model_file, exc)
        return None
    return model, report


def _write(key: str, folder: Path, model: Model, report: dict) -> Path | None:
    from vislam.eval.atomic import write_json, write_text

    try:
        folder.mkdir(parents=True, exist_ok=True)
        write_json(folder / f"{key}.json", report)
        write_text(folder / f"{key}.toml", model.to_toml())
    except OSError as exc:
        log.warning("model cache: cannot keep the model in %s (%s); it is used uncached",
                    folder, exc)
        return None
    return folder / f"{key}.toml"


def identified_model(seq: Sequence, config: FilterConfig = FilterConfig(),
                     settings: SmootherSettings = SmootherSettings(), *,
                     pairings: tuple[str, ...] | None = None,
                     folder: Path | None = None,
                     on_miss: Callable[[], None] | None = None) -> IdentifiedModel:
    """The identified model of ``seq`` (from the cache when it holds it); ``on_miss()`` is
    called before an identification runs (the cache does not hold it)."""
    from vislam.ekf.config import VELOCITY_PAIRINGS
    from vislam.graph.identification import identify_model

    pairings = tuple(VELOCITY_PAIRINGS if pairings is None else pairings)
    settings = settings.replace(compute_marginals=False)
    folder = cache_dir() if folder is None else Path(folder)
    key = cache_key(seq, config, settings, pairings)
    hit = _read(key, folder)
    if hit is not None:
        log.info("model cache: %s read from %s", seq.name, folder / f"{key}.toml")
        return IdentifiedModel(hit[0], hit[1], True, key, folder / f"{key}.toml")
    if on_miss is not None:
        on_miss()
    fit = identify_model(seq, config, settings, pairings=pairings)
    name = seq.name if seq.source is None else Path(seq.source).name
    model = fit.to_model(f"identified from {name} (EM around the smoother; vislam bench)")
    report = fit_report(fit)
    path = _write(key, folder, model, report)
    return IdentifiedModel(model, report, False, key, path)


__all__ = ["IdentifiedModel", "identified_model", "cache_dir", "cache_key", "sequence_digest",
           "fit_report", "IDENTIFICATION_VERSION"]
