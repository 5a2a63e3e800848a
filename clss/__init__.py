"""clss: a portable OpenCL inference engine for neural temporal supersampling."""
from .device import Device, DeviceError, KernelBuildError, get_device, list_devices, PRECISIONS

__version__ = "0.1.0"


def __getattr__(name):
    # Heavier subsystems load on first use, so `import clss` stays quick.
    if name == "Model":
        from .model import Model
        return Model
    if name == "Upscaler":
        from .upscaler import Upscaler
        return Upscaler
    if name == "Contract":
        from .pipeline.contract import Contract
        return Contract
    raise AttributeError(f"module 'clss' has no attribute {name!r}")


__all__ = ["Device", "DeviceError", "KernelBuildError", "get_device", "list_devices", "PRECISIONS",
           "Model", "Upscaler", "Contract"]
