"""``gnsscitygml:estimate``: observations + footprint layer + DEM -> heights layer (4PL-B).

The same job as ``gnss-citygml estimate`` (:func:`gnss_citygml.jobs.estimate_file`), with the
same defaults, read from the library's settings: the heights are the command line's. Its
inputs and options are those of the run (:class:`RunAlgorithm`), which ``report`` shares.
"""

from qgis.core import (
    QgsProcessing,
    QgsProcessingLayerPostProcessorInterface,
    QgsProcessingOutputNumber,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterField,
    QgsProcessingParameterFile,
    QgsProcessingParameterRasterLayer,
    QgsProcessingParameterVectorDestination,
)

from .algorithm import SIGNAL_MODEL_HELP, Algorithm, advanced, folder, option

LAYER = "heights"

#: The library's options (``gnss_citygml.options``) the algorithm offers, in order, and those
#: of them shown under "Advanced parameters".
_OPTIONS = (
    "MIN_ELEVATION",
    "MAX_ELEVATION",
    "RECEIVER_HEIGHT",
    "ANTENNA_HEIGHT",
    "INIT_THRESHOLD",
    "METHOD",
    "HEIGHT_RULE",
    "SIGNAL_MODEL",
    "LEVEL_PHONES",
    "MAX_ITER",
    "FIT_MAX_ITER",
    "MAX_RANGE",
    "POSITION_SD",
    "POSITION_DISTANCE",
    "POSITION_WINDOW",
    "CALIBRATION_SD",
    "CALIBRATION_WINDOW",
    "CALIBRATION_MATCHING",
    "CALIBRATION_HEIGHTS",
    "CALIBRATION_HEIGHTS_SD",
)
_ADVANCED = set(_OPTIONS[7:])

#: The help on the run's inputs (estimate, report).
INPUTS_HELP = """<b>Observations</b>: the observations table (Parquet or CSV: time_utc, \
receiver, lat, lon, h, constellation, svid, azimuth, elevation, cn0, with an empty cn0 for a \
blocked signal, and optionally position_sd, how far each position may be off: 1 m where it is \
empty), as written by <tt>gnss-citygml observe</tt> or "Turn GnssLogger logs into \
observations" from GnssLogger logs.
<b>Footprints</b>: building polygons (OS MasterMap, any GeoPackage; in British National Grid, \
or in ETRS89/WGS 84, converted with OSTN15).
<b>DEM</b>: the terrain in British National Grid with ODN heights."""

HELP = (
    """Estimates the height of every building footprint from the GNSS signals that \
smartphones received or lost around it, with 4PL-B (Lines & Basiri): for each building, a \
four-parameter logistic regression of "signal received" against the height at which each \
satellite ray crosses the footprint, co-trained with a C/N0 signal classifier.

"""
    + INPUTS_HELP
    + """

The output layer holds every footprint with its attributes and the estimate: height (m ODN: \
the 4PL's inflection point c; the height rule "paper" gives c + 1.5/b, which height_paper \
holds either way), height_lower and height_upper (the range), relative_height (above the \
ground), n_signals, \
converged and status (why a building has no height: never a guess). It opens styled: \
buildings coloured by height, hatched where there is no estimate, extruded in the 3D view.

"""
    + SIGNAL_MODEL_HELP
    + """

The same as <tt>gnss-citygml estimate</tt> on the command line, with the same defaults."""
)


class _Style(QgsProcessingLayerPostProcessorInterface):
    """Gives the loaded heights layer its default style from the GeoPackage (Processing loads
    layers without it): the toolkit's, which the writer saved there, or one the user saved as
    the default for this layer, which the writer left so."""

    instance = None

    @classmethod
    def create(cls):
        """A new one for each run, kept alive here: QGIS holds a pointer, not a reference, and
        deletes it once used; the algorithm that ran is a copy gone by then."""
        cls.instance = cls()
        return cls.instance

    def postProcessLayer(self, layer, context, feedback):  # noqa: N802 (the name QGIS calls)
        message, ok = layer.loadDefaultStyle()
        if not ok:
            feedback.pushWarning(f"the layer's style was not loaded: {message}")
        layer.triggerRepaint()


class RunAlgorithm(Algorithm):
    """The run's inputs and options, as parameters and as the job's arguments: what
    ``estimate`` and ``report`` share (as the command line's two commands do)."""

    def define_run(self):
        """Add the run's parameters: observations, footprints, DEM, id field, options, grids."""
        self.addParameter(
            QgsProcessingParameterFile(
                "OBSERVATIONS",
                "Observations (Parquet or CSV)",
                fileFilter="Observations (*.parquet *.csv);;All files (*)",
            )
        )
        self.addParameter(
            QgsProcessingParameterFeatureSource(
                "FOOTPRINTS", "Building footprints", [QgsProcessing.TypeVectorPolygon]
            )
        )
        self.addParameter(QgsProcessingParameterRasterLayer("DEM", "DEM (British National Grid)"))
        self.addParameter(
            QgsProcessingParameterField(
                "ID_FIELD",
                "Building id field (default: toid, id or fid)",
                parentLayerParameterName="FOOTPRINTS",
                optional=True,
            )
        )
        for name in _OPTIONS:
            parameter = option(name)
            self.addParameter(advanced(parameter) if name in _ADVANCED else parameter)
        self.addParameter(folder("GRID_DIR", "Folder with the OSTN15/OSGM15 grids"))

    def run_args(self, parameters, context, feedback):
        """The job's arguments for the run's parameters (:meth:`define_run`)."""
        footprints, layer = self.parameterAsCompatibleSourceLayerPathAndLayerName(
            parameters, "FOOTPRINTS", context, ["gpkg", "fgb", "shp", "gml"], "gpkg", feedback
        )
        dem = self.parameterAsRasterLayer(parameters, "DEM", context)
        return {
            "observations": self.parameterAsFile(parameters, "OBSERVATIONS", context),
            "footprints": footprints,
            "dem": dem.source(),
            "layer": layer or None,
            "id_field": self.optional_text(parameters, "ID_FIELD", context),
            **self.settings(parameters, _OPTIONS, context),
            "dem_crs": dem.crs().authid() or None,
            "grid_dir": self.optional_text(parameters, "GRID_DIR", context),
        }


class EstimateAlgorithm(RunAlgorithm):
    section = "estimate-observations-footprints-and-a-dem-to-heights"

    def name(self):
        return "estimate"

    def displayName(self):  # noqa: N802 (the name QGIS calls)
        return "Estimate building heights from GNSS (4PL-B)"

    def shortHelpString(self):  # noqa: N802 (the name QGIS calls)
        return HELP

    def define(self):
        self.define_run()
        self.addParameter(
            QgsProcessingParameterVectorDestination(
                "OUTPUT", "Heights", QgsProcessing.TypeVectorPolygon
            )
        )
        self.addOutput(QgsProcessingOutputNumber("BUILDINGS", "Buildings"))
        self.addOutput(QgsProcessingOutputNumber("CONVERGED", "Buildings with a height"))

    def job(self, parameters, context, feedback):
        output = self.parameterAsOutputLayer(parameters, "OUTPUT", context)
        args = {
            **self.run_args(parameters, context, feedback),
            "output": output,
            "overwrite": True,  # QGIS's file dialog has asked; a GeoPackage keeps other layers
        }
        result = self.run_job("estimate", args, feedback)
        feedback.pushInfo(
            f"{result['converged']} of {result['buildings']} buildings have a height -> {output}"
        )
        uri = f"{output}|layername={LAYER}"
        self._load_styled(context, output, uri)
        return {"OUTPUT": uri, "BUILDINGS": result["buildings"], "CONVERGED": result["converged"]}

    def _load_styled(self, context, output, uri):
        """Load the layer ``heights`` of the output (not the whole GeoPackage), styled."""
        if not context.willLoadLayerOnCompletion(output):
            return
        layers = context.layersToLoadOnCompletion()
        details = layers.pop(output)
        details.name = details.name or LAYER
        details.setPostProcessor(_Style.create())
        layers[uri] = details
        context.setLayersToLoadOnCompletion(layers)
