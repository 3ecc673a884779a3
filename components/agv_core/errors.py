"""Exceptions shared by the cores and the FMU adapters."""


class ParameterError(ValueError):
    """A parameter value is invalid.

    Parameters
    ----------
    name : str
        The parameter's name as the user sees it (the FMU variable name).
    message : str
        What is wrong with it.
    """

    def __init__(self, name: str, message: str) -> None:
        super().__init__(f"parameter '{name}': {message}")
        self.name = name


class ModelLimitError(RuntimeError):
    """The model reached a limit of its validity (a wheel lifts, the driven wheels cannot
    hold the speed): not a fault of the code nor of the host's calls, but the model cannot
    be stepped on. A core raises it from the step that reached the limit, its state at the
    end of that step (what a host reads after the refusal); the FMU slaves refuse the
    step with fmi2Error / fmi3Error (not Fatal) and log the message
    (agv_core.fmi.slave_base.SlaveLogic._step_failed)."""
