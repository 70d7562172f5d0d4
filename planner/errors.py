"""The planner's exceptions: one root, a few specific kinds.

Every message names the parameter or input, the value that was wrong and what to change,
so that the CLI can print it as one line and the service can pass it on as a problem
``detail`` unchanged.
"""

from __future__ import annotations


class PlannerError(Exception):
    """Root of every error the planner raises on purpose."""


class SceneError(PlannerError):
    """The model cannot be read or is not usable (empty, broken, non-finite, wrong format)."""


class UnsupportedFormatError(SceneError):
    """The file is not in a format the planner reads."""


class ParameterError(PlannerError, ValueError):
    """A parameter is out of range or inconsistent with another.

    ``parameter`` names it exactly as in the API (``dof_min_m``), so that a caller can point
    at the field.
    """

    def __init__(self, parameter: str, message: str) -> None:
        super().__init__(f"{parameter}: {message}")
        self.parameter = parameter


class NoCandidatesError(PlannerError):
    """No scanner position is left to consider."""


class NothingVisibleError(PlannerError):
    """No face qualifies from any candidate: there is nothing to plan for."""


class CancelledError(PlannerError):
    """The progress callback asked the pipeline to stop."""


class ClusterError(PlannerError):
    """The Dask cluster a plan was fanned out over failed it (``--dask-scheduler``,
    ``SCANPLAN_DASK_SCHEDULER``)."""


class SchedulerUnreachableError(ClusterError):
    """The Dask scheduler cannot be reached: the plan does not start."""

    def __init__(self, address: str, reason: object) -> None:
        super().__init__(
            f"the Dask scheduler at {address} cannot be reached: {reason}; check "
            "SCANPLAN_DASK_SCHEDULER (or --dask-scheduler), that the scheduler runs and "
            "that this machine can open a connection to it")
        self.address = address
        self.reason = reason

    def __reduce__(self) -> tuple[type[SchedulerUnreachableError], tuple[str, str]]:
        # rebuilt from its own arguments (a job's plan runs in a child process)
        return type(self), (self.address, str(self.reason))
