"""Exceptions raised by sc_fem (all in one place, meshio style).

Every error the package raises on bad input derives from :class:`ScFemError`, so
``except sc_fem.ScFemError`` catches all of them. Each also derives from the
closest builtin (``ValueError``, ``OSError``, ...) so generic handlers keep working.
"""

from __future__ import annotations


class ScFemError(Exception):
    """Base class of every sc_fem error."""


class InputError(ScFemError, ValueError):
    """An argument has the wrong shape, type or value (names the argument)."""


class MeshError(InputError):
    """A mesh is empty, degenerate, non-finite or has faces indexing missing vertices."""


class MeshFileError(ScFemError, OSError):
    """A mesh file is missing, unreadable, corrupted or of an unknown format."""


class MaterialError(InputError):
    """A material parameter is out of range (E <= 0, nu outside (-1, 0.5), rho <= 0, ...)."""


class ResolutionError(InputError):
    """A voxel resolution or pitch is too small, too large, or would not fit in memory."""


class BoundaryConditionError(InputError):
    """A boundary-condition spec cannot be parsed or selects nothing."""


class SolverError(ScFemError, RuntimeError):
    """A linear/eigen solve failed (e.g. a floating model under load)."""


class InstabilityError(SolverError):
    """A time integration blew up (non-finite state or runaway energy)."""


class FileFormatError(ScFemError, OSError):
    """An sc_fem file (modes, cube model, animation, reconstruction) is missing, truncated,
    corrupted, foreign or of another version."""


"""The old name of :class:`FileFormatError` (it was raised for every sc_fem file, not only mode files)."""


class RenderError(ScFemError, RuntimeError):
    """Off-screen rendering is not possible on this machine (says what to install)."""


class ScFemWarning(UserWarning):
    """A result is valid but probably not what was meant (most of a model dropped, an implausible
    size for the material, an energy drift): the message says what and how to change it."""


class OutputError(ScFemError, OSError):
    """An output path cannot be written (no permission, a path through a file, a virtual file
    system) or names a format that is not written."""
