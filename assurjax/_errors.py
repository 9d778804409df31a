"""Errors raised for bad input. Each names the scene field, group, link or point at fault."""


class AssurjaxError(ValueError):
    """Base of all errors about user input."""


class MechanismError(AssurjaxError):
    """A structural mistake in a mechanism (names, formation sequence, DOF, values)."""


class SceneError(AssurjaxError):
    """A scene file that cannot be read as a mechanism; the message names file and field."""


class AssemblyError(AssurjaxError):
    """A group cannot assemble at the requested driving coordinate."""

    def __init__(self, message: str, group: str | None = None):
        super().__init__(message)
        self.group = group
