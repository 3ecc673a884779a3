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
