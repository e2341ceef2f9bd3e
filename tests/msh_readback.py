"""A written ``.msh`` read back by Gmsh itself (the independent check of the files the
command writes): its nodes, 4-node quads and the nodes of its lines."""

import numpy as np


def read_msh(path, dim: int = 3):
    """Gmsh reading ``path`` back; the nodes' first ``dim`` coordinates.

    Returns:
        x (n, dim) the nodes (row = node tag − 1), quads (m, 4) the 4-node quads' node rows,
        and the sorted rows of the nodes on the mesh's lines (its boundary and curves).
    """
    import gmsh

    owns = not gmsh.isInitialized()
    if owns:
        gmsh.initialize(argv=[], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("read back")
        gmsh.open(str(path))
        assert list(gmsh.model.mesh.getElementTypes(2)) == [3], "4-node quads only"
        tags, coords, _ = gmsh.model.mesh.getNodes()
        x = np.zeros((int(tags.max()), 3))
        x[tags.astype(int) - 1] = coords.reshape(-1, 3)
        _, quads = gmsh.model.mesh.getElementsByType(3)
        _, _, lines = gmsh.model.mesh.getElements(1)
        on_lines = (np.unique(np.concatenate(lines).astype(int) - 1) if len(lines)
                    else np.zeros(0, dtype=int))
        return x[:, :dim], quads.astype(int).reshape(-1, 4) - 1, on_lines
    finally:
        if owns:
            gmsh.finalize()
        else:
            gmsh.model.remove()
