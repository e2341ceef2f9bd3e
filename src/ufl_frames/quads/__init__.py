"""From an integer-grid map to a quad mesh: extraction (:mod:`.extract`), the worst quads
improved (:mod:`.improve`), measures of a quad mesh (:mod:`.measures`) and its files
(:mod:`.msh`). Extraction, improvement and measures are pure NumPy; :mod:`.msh` uses Gmsh
and matplotlib."""
