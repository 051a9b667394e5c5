"""The world a buoy lives in: regions and their outlines (``regions``, ``osm``, ``lakes``), the exact coverage geometry
(``geometry``, ``coverage``, the union's compiled kernels in ``overlap``), the rewards of the paper (``rewards``),
the shore (``shore``), a buoy's sensors (``sensors``), currents (``currents``), distances through the water
(``geodesic``), the batched environment (``env``) and the one factory that makes an environment from the parameters
(``scenario``). Imports ``core`` only."""
