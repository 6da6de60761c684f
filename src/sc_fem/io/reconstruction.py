"""The reconstruction file (``.npz``, versioned): :func:`save_reconstruction` and :func:`load_reconstruction`.

It holds a :class:`~sc_fem.reconstruct.pipeline.Reconstruction`: the frames, the simulated, PDE and
B-spline curves (model units), their E_A / E_M errors, the PDE model's rates ``r`` and ``alpha``,
and the job's record (``meta``, JSON). :func:`reconstruct_to_file` is the whole job of
``sc-fem reconstruct``: read an animation, reconstruct it, write the file and a report.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .._atomic import atomic_path, save_npz_atomic
from ..errors import FileFormatError, InputError
from ..reconstruct.pde import check_frame_indices
from ..reconstruct.pipeline import ARRAYS, OPTIONAL, Reconstruction, markdown_report, reconstruct_animation
from ._npz import read_versioned_npz
from .animation import Animation, load_animation
from .report import JobResult

RECON_KIND = "sc_fem.reconstruction"
RECON_FORMAT_VERSION = 1


def save_reconstruction(path, result: Reconstruction) -> Path:
    """Write ``result`` to ``path`` (``.npz``, atomically); read it back with :func:`load_reconstruction`."""
    path = Path(path)
    if path.suffix.lower() != ".npz":
        raise InputError(f"a reconstruction is written as .npz, got {path.name!r}")
    arrays = {k: getattr(result, k) for k in ARRAYS}
    arrays.update({k: getattr(result, k) for k in OPTIONAL if getattr(result, k) is not None})
    return save_npz_atomic(path, format_version=np.int64(RECON_FORMAT_VERSION), kind=np.str_(RECON_KIND),
                           r=np.float64(result.r), alpha=np.float64(result.alpha),
                           meta_json=np.str_(json.dumps(result.meta)), **arrays)


def load_reconstruction(path) -> Reconstruction:
    """Read a file written by :func:`save_reconstruction` (or ``sc-fem reconstruct``).

    Raises
    ------
    FileFormatError
        Missing, corrupted, foreign or other-version file.
    """
    data = read_versioned_npz(path, kind=RECON_KIND, version=RECON_FORMAT_VERSION, what="reconstruction file")
    missing = [k for k in (*ARRAYS, "r", "alpha") if k not in data]
    if missing:
        raise FileFormatError(f"{path}: reconstruction file lacks {missing}")
    meta = json.loads(str(data["meta_json"])) if "meta_json" in data else {}
    return Reconstruction(**{k: data[k] for k in ARRAYS}, r=float(data["r"]), alpha=float(data["alpha"]),
                          **{k: data.get(k) for k in OPTIONAL}, meta=meta)


def reconstruct_to_file(animation: Any, output: str | Path, fit_frames: Sequence[int], *,
                        report: str | Path | None = None, frames_name: str = "fit_frames",
                        **options: Any) -> JobResult:
    """Reconstruct a vertex animation from a few frames and write the reconstruction file.

    Parameters
    ----------
    animation : Animation or path
        The animation (a file from ``sc-fem simulate`` or :func:`sc_fem.io.animation.save_animation`);
        a path is recorded in the file's ``meta["animation"]``.
    output : str or Path
        The reconstruction file (``.npz``, :func:`save_reconstruction`).
    fit_frames : sequence of int
        At least two strictly increasing frame indices to fit.
    report : str or Path, optional
        Also write the Markdown table of errors, timings and counts
        (:func:`sc_fem.reconstruct.pipeline.markdown_report`) here.
    frames_name : str
        What error messages call ``fit_frames`` (the command line: ``"--fit-frames"``).
    **options
        Keyword arguments of :func:`sc_fem.reconstruct.pipeline.reconstruct_animation`
        (``n_curves``, ``segments``, ``offset``, ``curves_from``, ...).

    Returns
    -------
    JobResult
        ``result`` the :class:`~sc_fem.reconstruct.pipeline.Reconstruction`; not ``ok`` when the PDE
        fit failed (its ``failures``; the files are written for inspection all the same).
    """
    anim = animation if isinstance(animation, Animation) else load_animation(animation)
    fit = check_frame_indices(np.asarray(fit_frames), anim.n_frames, name=frames_name)
    result = reconstruct_animation(anim, fit, **options)
    if not isinstance(animation, Animation):                       # "source": the mesh
        result = replace(result, meta={**result.meta, "animation": str(animation)})
    written = [save_reconstruction(output, result)]
    if report:
        with atomic_path(report) as tmp:
            tmp.write_text(markdown_report(result))
        written.append(Path(report))
    error = None if result.ok else (f"the PDE fit failed: {'; '.join(result.failures)} (the output was written "
                                    "for inspection)")
    return JobResult(written=written, result=result, text=f"{result.summary()}; wrote {output}", ok=result.ok,
                     error=error)
