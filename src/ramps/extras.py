"""What ramps needs beyond its base install, and one clear error when it is missing.

``pip install ramps-robotics`` brings what a node, a client and the
simulator need. The rest comes with an extra (pyproject.toml)::

    route   OR-Tools: the built-in ``route_plan`` program (the paper's workload)
    plots   matplotlib: ``ramps report``, the demo's report, ``ramps sim paper --plot``
    demo    both: ``ramps demo`` (``make demo``)

Code that needs one calls ``require`` before the import, so that a missing
extra is one line naming what to install, not a traceback.
"""

from __future__ import annotations

import importlib.util

from ramps.errors import ConfigError

#: top-level module -> the extra that installs it
EXTRA_OF = {"ortools": "route", "matplotlib": "plots"}


class MissingExtra(ConfigError, ModuleNotFoundError):
    """An optional dependency is not installed here; the message says which extra brings it."""


def missing(module: str) -> bool:
    """Whether ``module`` (a top-level package) cannot be imported here; nothing is imported."""
    try:
        return importlib.util.find_spec(module) is None
    except (ImportError, ValueError):
        return True


def require(module: str, what: str, extra: str | None = None) -> None:
    """Raise ``MissingExtra`` if ``module`` is not installed: ``what`` (the
    program or command that needs it) says what to install."""
    if missing(module):
        name = extra or EXTRA_OF.get(module, module)
        exc = MissingExtra(f"{what} needs {module}, which is not installed here: pip install 'ramps-robotics[{name}]'")
        exc.name = module
        raise exc
