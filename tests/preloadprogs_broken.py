"""A program module that fails while it is imported."""

raise RuntimeError("the map server is not configured")


def plan() -> None:  # never reached
    pass
