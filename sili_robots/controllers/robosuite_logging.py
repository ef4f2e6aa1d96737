"""robosuite's import-time warnings about optional extras, filtered from its logger.

Shared by the robosuite OSC controller (an ablation) and the Sawyer scene (which imports robosuite's
models); it lives with the controllers, the lower of the two layers.
"""

from __future__ import annotations

import logging

_QUIET = (
    "No private macro file found",
    "It is recommended to use a private macro file",
    "To setup, run:",
    "Could not import robosuite_models",
    "Could not load the mink-based whole-body IK",
)


class _DropKnownImportWarnings(logging.Filter):
    """robosuite warns about optional extras on import; they do not concern this scene."""

    def filter(self, record: logging.LogRecord) -> bool:
        msg = record.getMessage()
        return not any(msg.startswith(q) for q in _QUIET)


#: robosuite's logger
LOGGER = "robosuite_logs"


def quiet_robosuite_import() -> None:
    """Install the filter on robosuite's logger (before robosuite is first imported)."""
    logger = logging.getLogger(LOGGER)
    if not any(isinstance(f, _DropKnownImportWarnings) for f in logger.filters):
        logger.addFilter(_DropKnownImportWarnings())
