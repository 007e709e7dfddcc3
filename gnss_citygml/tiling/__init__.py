"""A run cut into square British National Grid tiles, for a city or a country.

:mod:`.grid` names the tiles and plans which receivers and buildings each needs;
:mod:`.partition` writes observations as Parquet by tile; :mod:`.run` runs 4PL-B over the tiles
(:func:`~.run.tiled_heights`, :func:`~.run.partitioned_heights`), in one process or on Dask
(:mod:`.cluster`, the only module that imports Dask); :mod:`.output` has the workers write the
heights tile by tile. It imports the stages (:mod:`gnss_citygml.stages`) and the model, never
the other way.
"""
