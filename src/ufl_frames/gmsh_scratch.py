"""A scratch Gmsh model: fresh inside a ``with`` block, Gmsh left as it was found.

Gmsh is imported on first use, so that the pure packages (``quads``) can import this
module without it.
"""

import contextlib

__all__ = ["scratch_model"]


@contextlib.contextmanager
def scratch_model(name: str, options: tuple[str, ...] = ("General.Terminal",)):
    """A fresh Gmsh model, current inside the block, Gmsh silent; afterwards Gmsh is
    finalised if it was started here, else the model is removed, the caller's model made
    current again and the numeric ``options`` (those the block may set) restored.

    Args:
        name: the model's name.
        options: Gmsh's numeric options the block may change.

    Yields:
        The ``gmsh`` module.
    """
    import gmsh

    owns = not gmsh.isInitialized()
    saved, previous = {}, None
    if owns:
        gmsh.initialize(argv=[], readConfigFiles=False, interruptible=False)
    else:
        saved = {k: gmsh.option.getNumber(k) for k in ("General.Terminal", *options)}
        previous = gmsh.model.getCurrent()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add(name)
        yield gmsh
    finally:
        if owns:
            gmsh.finalize()
        elif gmsh.isInitialized():
            try:
                gmsh.model.remove()
                if previous:
                    gmsh.model.setCurrent(previous)
            finally:
                for key, value in saved.items():
                    gmsh.option.setNumber(key, value)
