"""Errors a user can act on. The CLI prints them as one line and exits with code 2."""

from __future__ import annotations


class IllumError(Exception):
    """A user-facing error that names what is wrong and where.

    file/prim/attribute are optional parts of the location; str() gives one line such as
    ``stage.usda: /World/Key.inputs:intensity: value is NaN``.
    """

    def __init__(self, message: str, *, file: str = "", prim: str = "", attribute: str = ""):
        self.message = message
        self.file = file
        self.prim = prim
        self.attribute = attribute
        super().__init__(str(self))

    def __str__(self) -> str:
        where = []
        if self.file:
            where.append(self.file)
        if self.prim and self.attribute:
            where.append(f"{self.prim}.{self.attribute}")
        elif self.prim:
            where.append(self.prim)
        elif self.attribute:
            where.append(self.attribute)
        return (": ".join(where) + ": " if where else "") + self.message


class StageError(IllumError):
    """The stage cannot be read or holds values that cannot be rendered."""


class SettingsError(IllumError):
    """A render option (CLI flag, service field, RenderSettings attribute) is out of range."""


class SpecialFileError(StageError):
    """The stage, a layer or an asset is a FIFO, a device, a socket or a directory: reading it
    could block forever or never end, so it is refused before anything opens it."""
