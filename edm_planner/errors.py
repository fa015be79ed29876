"""Error codes shared by the core and every service response.

The values are mirrored one to one by the constants in
``edm_planner_msgs/msg/ErrorCode.msg``; a test keeps the two in step.
"""

from enum import IntEnum


class ErrorCode(IntEnum):
    """Outcome of a request (after moveit_msgs/MoveItErrorCodes)."""

    SUCCESS = 0
    INVALID_REQUEST = 1
    UNKNOWN_ID = 2
    FILE_ERROR = 3
    INVALID_GEOMETRY = 4
    ELECTRODE_IN_COLLISION = 5
    INFEASIBLE = 6
    TIMEOUT = 7
    INTERNAL = 8
    NOT_CERTIFIED = 9


class EdmError(Exception):
    """An error with a code a service can return and a message a user can act on.

    Parameters
    ----------
    code : ErrorCode
        Machine-readable category.
    message : str
        What went wrong, naming the key, file or value involved.
    """

    def __init__(self, code: ErrorCode, message: str):
        super().__init__(message)
        self.code = ErrorCode(code)
        self.message = message

    def __str__(self) -> str:
        return f"{self.code.name}: {self.message}"


class GeometryError(EdmError):
    """Invalid blisk or electrode geometry (bad values, impossible shapes)."""

    def __init__(self, message: str, code: ErrorCode = ErrorCode.INVALID_GEOMETRY):
        super().__init__(code, message)


class GeometryFileError(EdmError):
    """A geometry file that is missing, unreadable or not allowed."""

    def __init__(self, message: str):
        super().__init__(ErrorCode.FILE_ERROR, message)
