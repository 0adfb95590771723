"""OpenCV, imported only where images are read: the optional extra `jaxba[images]`."""

import types

INSTALL_HINT = "pip install 'jaxba[images]'"


class OpenCVMissingError(ImportError):
    """OpenCV (the `cv2` module) cannot be imported."""


def import_cv2() -> types.ModuleType:
    """The `cv2` module, one thread per process (the images are spread over processes).

    Raises `OpenCVMissingError` naming the extra to install when it is missing.
    """
    try:
        import cv2
    except ImportError as error:
        raise OpenCVMissingError(
            f"detecting targets in images needs OpenCV, which cannot be imported ({error});"
            f" install it with: {INSTALL_HINT}") from None
    cv2.setNumThreads(1)
    return cv2
