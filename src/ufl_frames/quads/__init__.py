"""From an integer-grid map to a quad mesh: its integer iso-lines (:mod:`.isolines`) and
the quads they bound (:mod:`.extract`), the worst quads improved (:mod:`.improve`),
measures of a quad mesh (:mod:`.measures`) and its files (:mod:`.msh`); from a seamless
map to a quad mesh by its T-mesh, valid by construction: exact charts (:mod:`.charts`),
the motorcycle graph (:mod:`.motorcycles`) and its rectangular patches (:mod:`.layout`),
integer arc lengths and the quads of every patch (:mod:`.patches`); the geometry's regions,
curves and points found on the quads and checked (:mod:`.features`). All pure NumPy/SciPy
but :mod:`.msh`, which uses Gmsh and matplotlib."""
