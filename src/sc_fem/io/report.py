"""What the file-writing jobs of :mod:`sc_fem.io` return and how they report as they go.

The jobs behind the ``sc-fem`` commands (:func:`sc_fem.io.voxelize.voxelize_to_file`,
:func:`sc_fem.io.batch.precompute_modes`, :func:`sc_fem.io.simulation.simulate_to_file`, ...) each
return a :class:`JobResult`: the files written, the job's main product, and its summary for a
person. With ``verbose=True`` they print every stage and its time on stderr (:func:`stage`).
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Iterator

from .._log import say


@dataclass(frozen=True, eq=False)
class JobResult:
    """The outcome of a file-writing job.

    Attributes
    ----------
    written : list of Path
        Files (or folders of frames) written, in order.
    result : object
        The job's main product (a CubeModel, ModalBasis, Recording, Reconstruction, BatchResult,
        ...), or None.
    text : str
        The summary for a person (what ``sc-fem`` prints; may be empty).
    ok : bool
        False when the result failed its acceptance test or a part of the job failed (the files
        were still written; the command exits with status 1).
    error : str or None
        Why it is not ok, as one sentence to report (None: nothing to add to :attr:`text`).
    """

    written: list = field(default_factory=list)
    result: Any = None
    text: str = ""
    ok: bool = True
    error: str | None = None

    def summary(self) -> str:
        """The job's summary for a person.

        Returns
        -------
        str
            Lines of text (empty when the job has nothing to say).
        """
        return self.text


@contextmanager
def stage(name: str, timings: dict, verbose: bool = False) -> Iterator[None]:
    """Time a stage: ``timings[name]`` in seconds, and with ``verbose`` ``[name] ...`` and
    ``[name] 1.23 s`` lines on the ``sc_fem`` logger (:mod:`sc_fem._log`).

    Parameters
    ----------
    name : str
        The stage's name.
    timings : dict
        Receives ``name: seconds`` when the stage ends without an error.
    verbose : bool
        Log the stage's start and time.

    Yields
    ------
    None
    """
    t0 = time.perf_counter()
    say(f"[{name}] ...", verbose)
    yield
    timings[name] = time.perf_counter() - t0
    say(f"[{name}] {timings[name]:.2f} s", verbose)


def table(rows: list[tuple[str, str]]) -> str:
    """Rows ``(key, value)`` as aligned lines, indented by two spaces.

    Parameters
    ----------
    rows : list of (str, str)

    Returns
    -------
    str
    """
    w = max(len(k) for k, _ in rows)
    return "\n".join(f"  {k:<{w}}  {v}" for k, v in rows)

