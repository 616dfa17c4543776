"""The error every input reader raises."""

__all__ = ["ViewError"]


class ViewError(ValueError):
    """An input that cannot be read as views; the message is one line naming the file."""
