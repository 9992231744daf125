"""assist: editable object-wise neural scenes (ASSIST) — load, edit in words or actions,
render to numpy, train and generate. Every library error is raised as `AssistError` with
its message. `assist.distributed` runs generation shards and trainings as Ray tasks
(`pip install 'assist[ray]'`)."""

from ._assist import *  # noqa: F401,F403 (the native module is the API)
from ._assist import AssistError  # noqa: F401 (named for readers and type checkers)
from . import distributed  # noqa: F401 (imports Ray only when used)
