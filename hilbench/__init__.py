"""hilbench: a hardware-in-the-loop serial bridge and bench for PMSM motor-control firmware."""

from hilbench.errors import HilbenchError

__version__ = "0.1.0"
__all__ = ["HilbenchError", "__version__"]
