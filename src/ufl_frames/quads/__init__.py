"""From an integer-grid map to a quad mesh: extraction (:mod:`.extract`), measures of a quad
mesh (:mod:`.measures`) and its files (:mod:`.msh`). Extraction and measures are pure
NumPy; :mod:`.msh` uses Gmsh."""
