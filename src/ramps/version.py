"""The version of ramps (the wire protocol's is ``ramps.core.messages.PROTOCOL``).

Rules: it imports nothing, so every layer may read it (``ramps.__version__``
is this one); a release bumps it beside ``version`` in ``pyproject.toml``.
"""

__version__ = "0.2.0"
