"""mocap: physics-based humanoid motion representations, composed by specs and plugins."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("mocap")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"
