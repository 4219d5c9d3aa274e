"""One line instead of a hundred when LeRobot's torchcodec probe fails for want of a system FFmpeg.

LeRobot picks its video decoder when a dataset or a training config is made
(``lerobot.utils.import_utils.get_safe_default_video_backend``): it imports torchcodec, which loads FFmpeg 8, 7, …, 4
from the system, and when none is installed it logs every loader's traceback before "Falling back to 'pyav'". The
fallback is right (this project's datasets hold point clouds, not videos), but a new user reads the tracebacks as a
broken install.

:func:`install` adds a :class:`logging.Filter` to that logger which, *only when no FFmpeg library can be found on the
system*, replaces that one warning by a single line saying what happens and how to get torchcodec. With FFmpeg
installed, torchcodec's failure is a real error (a version mismatch, a broken build) and is logged unchanged, as is
every other message.
"""

from __future__ import annotations

import ctypes.util
import functools
import logging

PROBE_LOGGER = "lerobot.utils.import_utils"
_FALLBACK_MARKER = "'torchcodec' is installed but cannot be loaded"
SHORT_MESSAGE = (
    "torchcodec found no system FFmpeg (libavutil), so LeRobot decodes videos with PyAV; this project's point-cloud "
    "datasets need no video decoding. To use torchcodec, install FFmpeg 4-8 (Debian/Ubuntu: apt install ffmpeg)."
)


@functools.cache
def system_ffmpeg_found() -> bool:
    """Whether the dynamic loader can find FFmpeg's ``libavutil`` (what torchcodec loads first)."""
    return ctypes.util.find_library("avutil") is not None


class MissingFFmpegFilter(logging.Filter):
    """Shortens LeRobot's torchcodec fallback warning to :data:`SHORT_MESSAGE` when no FFmpeg is installed."""

    def filter(self, record: logging.LogRecord) -> bool:
        if _FALLBACK_MARKER in record.getMessage() and not system_ffmpeg_found():
            record.msg, record.args = SHORT_MESSAGE, None
        return True


def install() -> None:
    """Attach :class:`MissingFFmpegFilter` to LeRobot's probe logger (once per process)."""
    logger = logging.getLogger(PROBE_LOGGER)
    if not any(isinstance(existing, MissingFFmpegFilter) for existing in logger.filters):
        logger.addFilter(MissingFFmpegFilter())
