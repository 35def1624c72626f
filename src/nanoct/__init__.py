"""nanoct: CT reconstruction with inexact (motion-perturbed) forward operators."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("nanoct")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
