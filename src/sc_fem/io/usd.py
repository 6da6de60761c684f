"""OpenUSD export (``.usd``, ``.usda``, ``.usdc``) through ``usd-core`` (the optional extra
``sc_fem[usd]``; ``pxr`` is imported only when a stage is built).

**Stage.** ``metersPerUnit`` 1 (points in metres: model points times the file's ``scale``, as in
glTF), ``upAxis`` the model's up axis (``up=``, ``sc-fem export --up``, default ``"z"``): z-up and
y-up data are written as they are with ``upAxis`` ``Z`` resp. ``Y``; USD has no x-up, so x-up data
are turned onto +Y by glTF's quarter turn about z, ``(x, y, z) -> (-y, x, z)``, and ``upAxis`` is
``Y``. The rotation is the root prim's ``scfem:modelToStage`` (stage point = R @ (scale * model
point)). The default prim is ``/Model``; ``customLayerData["sc_fem"]`` records kind, source, up
axis, units and, for a baked playback, what was baked.

**Mode file** (:class:`~sc_fem.ModalBasis`): ``/Model`` is a ``SkelRoot`` holding

* ``/Model/Mesh``: a ``Mesh`` (``subdivisionScheme`` none, double-sided, a grey dielectric
  ``UsdPreviewSurface`` at ``/Model/Looks/Default``) with vertex ``normals`` (as the glTF's:
  smooth across UV seams, creases kept, or the source file's) and ``primvars:st`` when the source
  mesh is given (``mesh=``; a mode file stores no UVs). A point set is a ``Points`` prim.
* one ``BlendShape`` per mode, ``/Model/Mesh/mode_K``: ``offsets`` = ``s_k phi_k`` (metres,
  turned by R; ``s_k`` of :func:`sc_fem.io.gltf.mode_scales`: weight 1 moves the largest vertex by
  ``amplitude`` times the bounding-box diagonal), ``normalOffsets`` (normals of the displaced
  mesh minus the rest normals) and the attributes ``scfem:mode`` (int), ``scfem:frequencyHz``,
  ``scfem:dampingRatio``, ``scfem:modeScale`` (``s_k``, m kg^1/2: the modal coordinate
  ``q_k = w_k s_k``) and ``scfem:rigid``; ``/Model`` carries the same per mode as arrays
  (``scfem:frequenciesHz``, ``scfem:dampingRatios``, ``scfem:modeScales``).
* ``/Model/Skel``, a ``Skeleton`` without joints bound to the mesh (UsdSkel applies blend shapes
  through a skeleton), with ``/Model/Skel/Anim``, a ``SkelAnimation`` naming every blend shape.
  Its ``blendShapeWeights`` are 0 (the rest shape), or, for a baked playback (``impulse=`` or
  ``mode=``, solved exactly as by :class:`~sc_fem.ModalPlayer`, the same motion as the glTF
  export bakes), time samples at the time codes ``0 .. T-1`` with ``timeCodesPerSecond`` =
  ``framesPerSecond`` = ``fps``. The weights are signed and not limited to [-1, 1] (USD clamps
  nothing; ``s_k`` is not widened as in glTF).

**Vertex animation** (``sc-fem simulate`` output): ``/Model`` is an ``Xform`` with ``/Model/Mesh``
whose ``points``, ``normals`` and ``extent`` are time-sampled, one sample per frame: frame ``i``
at time code ``(t_i - t_0) * fps`` (an integer ``i`` for the uniform frames ``simulate`` writes),
``fps`` the run's frame rate ``(T - 1) / (t_{T-1} - t_0)``, start and end time codes set. The
default ``points`` are the rest shape. An animation without a recorded ``scale`` is written in its
own units (``metersPerUnit`` 1 all the same, ``customLayerData`` says so).

Points, offsets, normals and UVs are float32.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .._atomic import atomic_path
from .._validate import positive_scalar
from ..errors import InputError, OutputError, ScFemError
from ..modes.player import ModalPlayer
from ..units import up_axis
from .animation import Animation, frame_rate
from .gltf import DEFAULT_AMPLITUDE, UP_TO_GLTF, _load, _surface, mode_scales
from .normals import _Normals

USD_SUFFIXES = (".usd", ".usda", ".usdc")
"""What :func:`export_usd` writes: ``.usda`` text, ``.usdc`` and ``.usd`` binary (crate)."""

INSTALL_HINT = "pip install 'sc_fem[usd]'"


def _pxr():
    """The ``pxr`` modules used here, or a :class:`ScFemError` naming the extra to install."""
    try:
        from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, UsdSkel, Vt
    except ImportError:
        raise ScFemError(f"USD export needs the OpenUSD Python package usd-core (module pxr), which is not "
                         f"installed: {INSTALL_HINT}") from None
    return Gf, Sdf, Usd, UsdGeom, UsdShade, UsdSkel, Vt


def stage_axes(up: str) -> tuple[np.ndarray, str]:
    """The rotation onto the stage and the stage's ``upAxis`` for a model whose up axis is ``up``.

    Parameters
    ----------
    up : {"z", "y", "x"}
        The model's up axis.

    Returns
    -------
    R : ndarray, shape (3, 3)
        Stage point = ``R @ model point`` (a proper rotation; the identity for ``"z"`` and ``"y"``).
    up_axis : {"Z", "Y"}
        The stage's ``upAxis`` metadata.
    """
    up_axis(up)
    if up == "x":
        return np.asarray(UP_TO_GLTF["x"], dtype=float), "Y"
    return np.eye(3), up.upper()


def _f3(Vt, a: np.ndarray):
    return Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(a, dtype=np.float32))


def _new_stage(pxr, up_axis: str, fps: float | None, n_codes: int, info: dict):
    Gf, Sdf, Usd, UsdGeom, UsdShade, UsdSkel, Vt = pxr
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z if up_axis == "Z" else UsdGeom.Tokens.y)
    if fps is not None:
        stage.SetTimeCodesPerSecond(fps)
        stage.SetFramesPerSecond(fps)
        stage.SetStartTimeCode(0.0)
        stage.SetEndTimeCode(float(max(n_codes - 1, 0)))
    stage.GetRootLayer().customLayerData = {"sc_fem": info}
    stage.GetRootLayer().documentation = f"sc_fem export: {info['kind']} of {info.get('source', '?')}"
    return stage


def _material(pxr, stage, prim) -> None:
    """A grey dielectric UsdPreviewSurface (metallic 0, roughness 0.6), as the glTF's default."""
    Gf, Sdf, Usd, UsdGeom, UsdShade, UsdSkel, Vt = pxr
    UsdGeom.Scope.Define(stage, "/Model/Looks")
    mat = UsdShade.Material.Define(stage, "/Model/Looks/Default")
    shader = UsdShade.Shader.Define(stage, "/Model/Looks/Default/Surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.8, 0.8, 0.8))
    shader.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.0)
    shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.6)
    mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(prim).Bind(mat)


def _surface_prim(pxr, stage, verts: np.ndarray, faces: np.ndarray, normals, uv, diag: float):
    """``/Model/Mesh`` (or a ``Points`` prim for a point set) at rest; returns the schema object."""
    Gf, Sdf, Usd, UsdGeom, UsdShade, UsdSkel, Vt = pxr
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(faces):
        geom = UsdGeom.Mesh.Define(stage, "/Model/Mesh")
        geom.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, dtype=np.int32)))
        geom.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces.ravel().astype(np.int32)))
        geom.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        geom.CreateDoubleSidedAttr(True)
        if normals is not None:
            geom.CreateNormalsAttr(_f3(Vt, normals))
            geom.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    else:
        geom = UsdGeom.Points.Define(stage, "/Model/Mesh")
        geom.CreateWidthsAttr(Vt.FloatArray.FromNumpy(np.full(len(verts), 0.005 * diag, dtype=np.float32)))
        geom.SetWidthsInterpolation(UsdGeom.Tokens.vertex)
    geom.CreatePointsAttr(_f3(Vt, verts))
    geom.CreateExtentAttr(_f3(Vt, np.stack([verts.min(axis=0), verts.max(axis=0)])))
    geom.CreateDisplayColorAttr([Gf.Vec3f(0.8, 0.8, 0.8)])
    if uv is not None:
        st = UsdGeom.PrimvarsAPI(geom).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
        st.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(uv, dtype=np.float32)))
    _material(pxr, stage, geom.GetPrim())
    return geom


def _attr(prim, Sdf, name: str, type_name: str, value, doc: str) -> None:
    attr = prim.CreateAttribute(name, getattr(Sdf.ValueTypeNames, type_name), custom=True)
    attr.Set(value)
    attr.SetDocumentation(doc)


def _usd_uv(uv):
    """The source UVs with USD's (and OBJ's) bottom-left origin: :func:`_surface` flips ``v`` for glTF."""
    return None if uv is None else np.column_stack([uv[:, 0], 1.0 - uv[:, 1]])


def _modes_stage(pxr, basis, *, amplitude: float, impulse, mode, duration: float, fps: float, up: str, mesh):
    Gf, Sdf, Usd, UsdGeom, UsdShade, UsdSkel, Vt = pxr
    amplitude = positive_scalar(amplitude, "amplitude")
    if impulse is not None and mode is not None:
        raise InputError("give impulse or mode for the baked playback, not both")
    R, up_axis = stage_axes(up)
    rest = np.asarray(basis.vertices, dtype=float)
    uv, file_normals = _surface(mesh, rest)
    s = mode_scales(basis, amplitude)                                    # m kg^1/2, (k,)
    info = {"kind": "modes", "source": str(basis.source), "up": up, "units": "m",
            "metersPerModelUnit": float(basis.scale), "amplitude": float(amplitude),
            "encoding": "one BlendShape per mode, offsets = modeScale * mode shape (m); weight w_k gives the "
                        "modal coordinate q_k = w_k * modeScale_k (m kg^0.5)"}
    weights = times = None
    if impulse is not None or mode is not None:                          # the motion gltf.py bakes
        player = ModalPlayer(basis)
        if impulse is not None:
            vertex, J = impulse
            player.impulse(int(vertex), J)
            info["playback"] = f"impulse {list(map(float, J))} N s on vertex {int(vertex)}"
        else:
            player.excite(int(mode), amplitude * float(np.linalg.norm(np.ptp(rest, axis=0))))
            info["playback"] = f"mode {int(mode)} released from weight 1"
        fps = positive_scalar(fps, "fps")
        times = player.times(duration, fps)
        q = player.coordinates(times)                                    # (T, k), exact
        weights = np.where(s > 0, q / np.where(s > 0, s, 1.0), 0.0)
        info.update(fps=float(fps), durationSeconds=float(times[-1]), frames=int(len(times)))
    stage = _new_stage(pxr, up_axis, None if times is None else fps, 0 if times is None else len(times), info)
    root = UsdSkel.Root.Define(stage, "/Model")
    stage.SetDefaultPrim(root.GetPrim())
    verts = rest * basis.scale @ R.T
    normal_fn = _Normals(verts, basis.faces) if len(basis.faces) else None
    n0 = None if normal_fn is None else normal_fn(verts)
    diag = float(np.linalg.norm(np.ptp(verts, axis=0)))
    geom = _surface_prim(pxr, stage, verts, basis.faces, n0 if file_normals is None else file_normals @ R.T,
                         _usd_uv(uv), diag)
    skel = UsdSkel.Skeleton.Define(stage, "/Model/Skel")
    skel.CreateJointsAttr([])
    anim = UsdSkel.Animation.Define(stage, "/Model/Skel/Anim")
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])
    width = len(str(max(basis.n_modes - 1, 0)))
    names = [f"mode_{j:0{width}d}" for j in range(basis.n_modes)]
    d = np.asarray(basis.modes, dtype=float) * s[:, None, None] @ R.T    # (k, n, 3) metres
    for j, name in enumerate(names):                                     # a loop over modes
        shape = UsdSkel.BlendShape.Define(stage, f"/Model/Mesh/{name}")
        shape.CreateOffsetsAttr(_f3(Vt, d[j]))
        if normal_fn is not None:
            shape.CreateNormalOffsetsAttr(_f3(Vt, normal_fn(verts + d[j]) - n0))
        prim = shape.GetPrim()
        _attr(prim, Sdf, "scfem:mode", "Int", j, "index of the mode in the mode file")
        _attr(prim, Sdf, "scfem:frequencyHz", "Double", float(basis.frequencies[j]), "natural frequency, Hz")
        _attr(prim, Sdf, "scfem:dampingRatio", "Double", float(basis.damping[j]), "damping ratio zeta")
        _attr(prim, Sdf, "scfem:modeScale", "Double", float(s[j]),
              "m kg^0.5: weight w gives the modal coordinate q = w * modeScale; offsets = modeScale * mode shape")
        _attr(prim, Sdf, "scfem:rigid", "Bool", bool(basis.rigid[j]), "a rigid-body mode (frequency 0)")
    binding = UsdSkel.BindingAPI.Apply(geom.GetPrim())
    binding.CreateSkeletonRel().SetTargets([skel.GetPath()])
    binding.CreateBlendShapesAttr(names)
    binding.CreateBlendShapeTargetsRel().SetTargets([Sdf.Path(f"/Model/Mesh/{n}") for n in names])
    anim.CreateBlendShapesAttr(names)
    attr = anim.CreateBlendShapeWeightsAttr(Vt.FloatArray.FromNumpy(np.zeros(len(names), dtype=np.float32)))
    if weights is not None:
        w32 = weights.astype(np.float32)
        for i in range(len(w32)):                                        # a loop over frames
            attr.Set(Vt.FloatArray.FromNumpy(w32[i]), Usd.TimeCode(float(i)))
    rp = root.GetPrim()
    for name, values, doc in (("frequenciesHz", basis.frequencies, "Hz, per mode"),
                              ("dampingRatios", basis.damping, "damping ratio zeta, per mode"),
                              ("modeScales", s, "m kg^0.5, per mode")):
        _attr(rp, Sdf, f"scfem:{name}", "DoubleArray", Vt.DoubleArray.FromNumpy(np.asarray(values, dtype=float)), doc)
    _root_axes(rp, Sdf, Gf, R, up, float(basis.scale))
    return stage


def _root_axes(prim, Sdf, Gf, R: np.ndarray, up: str, scale: float) -> None:
    _attr(prim, Sdf, "scfem:modelUp", "Token", up, "the model's up axis")
    _attr(prim, Sdf, "scfem:modelToStage", "Matrix3d", Gf.Matrix3d(*R.ravel().tolist()),
          "stage point = modelToStage @ (metersPerModelUnit * model point); row-major rows")
    _attr(prim, Sdf, "scfem:metersPerModelUnit", "Double", scale, "metres per unit of the source model")


def _animation_stage(pxr, anim, *, fps: float, up: str, mesh):
    Gf, Sdf, Usd, UsdGeom, UsdShade, UsdSkel, Vt = pxr
    R, up_axis = stage_axes(up)
    recorded = anim.meta.get("scale") if isinstance(anim.meta, dict) else None
    known = isinstance(recorded, (int, float)) and bool(np.isfinite(recorded)) and recorded > 0
    scale, units = (float(recorded), "m") if known else (1.0, "model units (the file records no scale)")
    t = np.asarray(anim.times, dtype=float)
    T = len(t)
    rate = frame_rate(t, fps)
    codes = (t - t[0]) * rate
    if np.allclose(codes, np.arange(T), rtol=0, atol=1e-6):
        codes = np.arange(T, dtype=float)
    info = {"kind": "vertex_animation", "source": str(anim.meta.get("source", "?")), "up": up, "units": units,
            "metersPerModelUnit": scale, "fps": rate, "frames": T, "firstFrameSeconds": float(t[0]),
            "timeCodes": "time code (t - firstFrameSeconds) * fps"}
    stage = _new_stage(pxr, up_axis, rate, 0, info)
    stage.SetEndTimeCode(float(codes[-1]))
    root = UsdGeom.Xform.Define(stage, "/Model")
    stage.SetDefaultPrim(root.GetPrim())
    rest = np.asarray(anim.rest_vertices, dtype=float)
    uv, file_normals = _surface(mesh, rest)
    verts = rest * scale @ R.T
    pos = np.asarray(anim.positions, dtype=float) * scale @ R.T         # (T, n, 3)
    faces = np.asarray(anim.faces, dtype=np.int64).reshape(-1, 3)
    normal_fn = _Normals(verts, faces) if len(faces) else None
    rest_normals = None if normal_fn is None else (normal_fn(verts) if file_normals is None else file_normals @ R.T)
    diag = float(np.linalg.norm(np.ptp(verts, axis=0)))
    geom = _surface_prim(pxr, stage, verts, faces, rest_normals, _usd_uv(uv), diag)
    lo, hi = pos.min(axis=1), pos.max(axis=1)
    points, extent = geom.GetPointsAttr(), geom.GetExtentAttr()
    normals = geom.GetNormalsAttr() if normal_fn is not None else None
    for i in range(T):                                                   # a loop over frames
        code = Usd.TimeCode(float(codes[i]))
        points.Set(_f3(Vt, pos[i]), code)
        extent.Set(_f3(Vt, np.stack([lo[i], hi[i]])), code)
        if normals is not None:
            normals.Set(_f3(Vt, normal_fn(pos[i])), code)
    _root_axes(root.GetPrim(), Sdf, Gf, R, up, scale)
    return stage


def usd_stage(source: Any, *, amplitude: float = DEFAULT_AMPLITUDE, impulse: tuple | None = None,
              mode: int | None = None, duration: float = 2.0, fps: float = 30.0, up: str = "z",
              mesh: Any = None) -> Any:
    """The in-memory USD stage :func:`export_usd` writes (see the module docstring for the layout).

    Parameters
    ----------
    source : ModalBasis, Animation or path
        A mode file (one blend shape per mode) or a vertex animation (time-sampled points).
    amplitude : float
        Largest displacement of a mode at weight 1, fraction of the bounding-box diagonal.
    impulse : (int, (float, float, float)), optional
        Bake the exact response to an impulse (N s) on a source vertex as blend-shape weights.
    mode : int, optional
        Bake this mode released from weight 1.
    duration : float
        Seconds of baked playback.
    fps : float
        Samples (time codes) per second of a baked playback; an animation keeps its own frame rate.
    up : {"z", "y", "x"}
        The model's up axis (the stage's ``upAxis``; x-up data are turned onto +Y).
    mesh : str, Path or trimesh.Trimesh, optional
        The source mesh with the file's vertices in the same order: its UVs become ``primvars:st``
        and its file normals (if any) the rest normals.

    Returns
    -------
    pxr.Usd.Stage
        In memory (``stage.GetRootLayer().Export(path)`` writes it).

    Raises
    ------
    ScFemError
        ``usd-core`` (module ``pxr``) is not installed.
    InputError
        Bad options (``impulse``/``mode`` for an animation, both given, a bad ``up``).
    """
    pxr = _pxr()
    obj = _load(source)
    if isinstance(obj, Animation):
        if impulse is not None or mode is not None:
            raise InputError("impulse / mode apply to mode files; an animation is exported as it is")
        return _animation_stage(pxr, obj, fps=fps, up=up, mesh=mesh)
    return _modes_stage(pxr, obj, amplitude=amplitude, impulse=impulse, mode=mode, duration=duration, fps=fps,
                        up=up, mesh=mesh)


def export_usd(source: Any, path: str | Path, *, amplitude: float = DEFAULT_AMPLITUDE, impulse: tuple | None = None,
               mode: int | None = None, duration: float = 2.0, fps: float = 30.0, up: str = "z",
               mesh: Any = None) -> Path:
    """Write a mode file (modes as UsdSkel blend shapes) or a vertex animation (time-sampled
    points) as OpenUSD, atomically: a failed export leaves no file.

    Parameters
    ----------
    source : ModalBasis, Animation or path
        A mode file or a ``sc-fem simulate`` animation.
    path : str or Path
        ``.usda`` (text), ``.usdc`` or ``.usd`` (binary crate).
    amplitude : float
        Largest displacement of a mode at weight 1, fraction of the bounding-box diagonal.
    impulse : (int, (float, float, float)), optional
        Bake the exact damped response to this impulse (N s) on a vertex as blend-shape weights.
    mode : int, optional
        Bake mode ``mode`` released from weight 1.
    duration : float
        Seconds of baked playback.
    fps : float
        Time codes per second of a baked playback.
    up : {"z", "y", "x"}
        The model's up axis.
    mesh : str, Path or trimesh.Trimesh, optional
        The source mesh (same vertices): UVs and file normals.

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    ScFemError
        ``usd-core`` is not installed (the message names ``pip install 'sc_fem[usd]'``).
    InputError
        A suffix other than ``.usd``, ``.usda``, ``.usdc``, or bad options.
    """
    path = Path(path)
    kind = path.suffix.lower()
    if kind not in USD_SUFFIXES:
        raise InputError(f"USD is written as {', '.join(USD_SUFFIXES)}, got {path.name!r}")
    stage = usd_stage(source, amplitude=amplitude, impulse=impulse, mode=mode, duration=duration, fps=fps, up=up,
                      mesh=mesh)
    with atomic_path(path, suffix=kind) as tmp:
        if not stage.GetRootLayer().Export(str(tmp)):          # the suffix picks text or crate
            raise OutputError(f"cannot write {path}: the USD library refused to write the layer")
    return path
