"""The meshes of nested iteration: how many levels, and the coarser meshes of a domain.

::

    fine = build(comm, "piano", 0.0125)
    domains = nested_domains(comm, "piano", fine, "auto", mesh_size=0.0125)
    field = FrameField.nested(domains)                        # coarsest first, ``fine`` last

Level k of L (0 the coarsest) is the shape meshed by Gmsh at 2^(L−1−k) times the size of
the finest, or, with ``nested_meshes``, the coarsest mesh split L−1−k times
(:func:`ufl_frames.mesh.build_nested`). ``levels="auto"`` takes :func:`auto_levels`
of the finest mesh; a coarse mesh that Gmsh cannot make, or that loses a hole, then ends
the coarsening instead of the run. Importing this module starts nothing (no PETSc, no
DOLFINx): the command reads :data:`MAX_LEVELS` before PETSc reads its options.
"""

__all__ = ["MAX_LEVELS", "NESTED_COARSEST", "auto_levels", "check_levels",
           "check_same_topology", "nested_domains"]

#: At most this many levels of nested iteration (each halves the mesh size).
MAX_LEVELS = 8
#: ``levels="auto"`` keeps the coarsest mesh at this many triangles or more: below, MBO's
#: singularities and the coarse solution are too far from the fine mesh's to help.
NESTED_COARSEST = 1500


def auto_levels(num_cells: int) -> int:
    """The levels of ``--levels auto`` for a finest mesh of ``num_cells`` triangles: as
    many halvings of the mesh size as keep the coarsest mesh at :data:`NESTED_COARSEST`
    triangles or more (a quarter of the triangles per level), at most :data:`MAX_LEVELS`."""
    levels = 1
    while levels < MAX_LEVELS and num_cells / 4.0**levels >= NESTED_COARSEST:
        levels += 1
    return levels


def check_levels(levels, name_or_path: str, conformal: bool) -> None:
    """Raise ValueError unless ``levels`` is 'auto' or a whole number from 1 to
    :data:`MAX_LEVELS`, and, above 1, of a geometry Gmsh meshes (not a ``.msh``) and a
    TAO solve (not ``conformal``).

    Args:
        levels: the number of meshes asked for, or 'auto'.
        name_or_path: the geometry, a built-in shape's name or a file.
        conformal: the run is the conformal scale (no TAO solve).

    Raises:
        ValueError: ``levels`` is neither 'auto' nor an integer from 1 to
            :data:`MAX_LEVELS`, or above 1 with a ``.msh`` or with ``conformal``.
    """
    if levels == "auto":
        return
    if isinstance(levels, bool) or not isinstance(levels, int) or not 0 < levels <= MAX_LEVELS:
        raise ValueError(f"levels must be 'auto' or an integer from 1 to {MAX_LEVELS}, "
                         f"got {levels!r}")
    if levels == 1:
        return
    if str(name_or_path).lower().endswith(".msh"):
        raise ValueError("--levels needs a geometry Gmsh can mesh at several sizes, not a .msh")
    if conformal:
        raise ValueError("--levels and --conformal cannot be combined (no TAO solve to nest)")


def check_same_topology(level, domain, factor) -> None:
    """Raise :class:`~ufl_frames.mesh.GeometryError` unless the coarse ``level`` (at
    size factor ``factor``) keeps ``domain``'s holes and thin parts (its Euler
    characteristic).

    Args:
        level: the coarse :class:`~ufl_frames.mesh.Domain`.
        domain: the finest :class:`~ufl_frames.mesh.Domain`, at the size asked for.
        factor: the size factor ``level`` was meshed at (named in the message).

    Raises:
        GeometryError: the two Euler characteristics differ.
    """
    from ufl_frames import mesh as meshes

    if level.euler_characteristic != domain.euler_characteristic:
        raise meshes.GeometryError(
            f"at size factor {factor:g} the mesh has Euler characteristic "
            f"{level.euler_characteristic}, not {domain.euler_characteristic} "
            "(a hole or a thin part is lost)")


def _say_nothing(text: str) -> None:
    pass


def nested_domains(comm, name_or_path: str, domain, levels="auto", mesh_size=None,
                   size_factor: float = 1.0, nested_meshes: bool = False,
                   drop_failing: bool | None = None, say=None, **limit) -> list:
    """The meshes of nested iteration ending at ``domain``, coarsest first (collective).

    Args:
        comm: the communicator ``domain`` lives on.
        name_or_path: the geometry ``domain`` was built from
            (:func:`ufl_frames.mesh.build`).
        domain: the finest mesh, at the size asked for.
        levels: how many meshes, or 'auto' (:func:`auto_levels` of ``domain``, one for a
            ``.msh``, which cannot be re-meshed).
        mesh_size: the mesh size ``domain`` was built with (None: the shape's default).
        size_factor: the size factor ``domain`` was built with.
        nested_meshes: the coarsest mesh split into the finer ones
            (:func:`ufl_frames.mesh.build_nested`; its finest replaces ``domain``)
            instead of every level meshed by Gmsh.
        drop_failing: a coarse level that Gmsh cannot make or that loses a hole ends the
            coarsening there (with ``nested_meshes``: one level fewer) instead of raising;
            None: where ``levels`` is 'auto'.
        say: called with a line of progress (a level being meshed, a level dropped).
        **limit: ``max_triangles``, ``time_limit`` and ``resolve_features`` for
            :func:`~ufl_frames.mesh.build`.

    Returns:
        The list of :class:`~ufl_frames.mesh.Domain` records, ``domain`` (or its
        nested twin) last; ``[domain]`` for one level.

    Raises:
        GeometryError: a coarse level that Gmsh cannot make or that loses a hole, where
            ``drop_failing`` is false.
    """
    from ufl_frames import mesh as meshes

    say = _say_nothing if say is None else say
    automatic = levels == "auto" if drop_failing is None else drop_failing
    if levels == "auto":
        can_coarsen = not str(name_or_path).lower().endswith(".msh")
        levels = auto_levels(domain.num_cells) if can_coarsen else 1
    if nested_meshes:
        return _split_levels(comm, name_or_path, domain, levels, mesh_size, size_factor,
                             limit, automatic, say)
    coarse = []  # every level meshed by Gmsh
    for k in range(levels - 1, 0, -1):
        say(f"meshing level {levels - 1 - k} (size factor {2**k:g}) ...")
        try:
            level = meshes.build(comm, name_or_path, mesh_size, size_factor * 2**k, **limit)
            check_same_topology(level, domain, 2**k)
        except meshes.GeometryError as e:
            if not automatic:
                raise meshes.GeometryError(f"level {levels - 1 - k} of --levels: {e}") from e
            say(f"  note: no coarser level: {e}")
            coarse = []  # the coarser levels are worse still: start from the finer ones
            continue
        coarse.append(level)
    return [*coarse, domain]


def _split_levels(comm, name_or_path, domain, levels, mesh_size, size_factor, limit,
                  automatic, say) -> list:
    """:func:`nested_domains` with ``nested_meshes``: the levels of
    :func:`ufl_frames.mesh.build_nested`; where ``automatic``, a coarsest mesh that
    fails or loses a hole means one level fewer; ``[domain]`` where one level is left."""
    from ufl_frames import mesh as meshes

    while levels > 1:
        say(f"meshing {levels} nested levels (the coarsest at size factor "
            f"{2**(levels - 1):g}, split {levels - 1} time(s)) ...")
        try:
            hierarchy = meshes.build_nested(comm, name_or_path, levels, mesh_size,
                                              size_factor, **limit)
            check_same_topology(hierarchy[0], domain, 2**(levels - 1))
        except meshes.GeometryError as e:
            if not automatic:
                raise meshes.GeometryError(f"--levels {levels} --nested-meshes: {e}") from e
            say(f"  note: {e}: one level fewer")
            levels -= 1
            continue
        return hierarchy
    return [domain]
