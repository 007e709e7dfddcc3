"""``gnsscitygml:estimate``: observations + footprint layer + DEM -> heights layer (4PL-B).

The same job as ``gnss-citygml estimate`` (:func:`gnss_citygml.jobs.estimate_file`), with the
same defaults, read from the library's settings: the heights are the command line's.
"""

from qgis.core import (
    QgsProcessing,
    QgsProcessingLayerPostProcessorInterface,
    QgsProcessingOutputNumber,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFeatureSource,
    QgsProcessingParameterField,
    QgsProcessingParameterFile,
    QgsProcessingParameterNumber,
    QgsProcessingParameterRasterLayer,
    QgsProcessingParameterVectorDestination,
)

from .algorithm import (
    HEIGHT_RULE,
    LEVEL_PHONES,
    SIGNAL_MODEL,
    SIGNAL_MODEL_HELP,
    Algorithm,
    advanced,
    choice,
    folder,
)

LAYER = "heights"

HELP = (
    """Estimates the height of every building footprint from the GNSS signals that \
smartphones received or lost around it, with 4PL-B (Lines & Basiri): for each building, a \
four-parameter logistic regression of "signal received" against the height at which each \
satellite ray crosses the footprint, co-trained with a C/N0 signal classifier.

<b>Observations</b>: the observations table (Parquet or CSV: time_utc, receiver, lat, lon, h, \
constellation, svid, azimuth, elevation, cn0, with an empty cn0 for a blocked signal, and \
optionally position_sd, how far each position may be off: 1 m where it is empty), as written \
by <tt>gnss-citygml observe</tt> from GnssLogger logs.
<b>Footprints</b>: building polygons (OS MasterMap, any GeoPackage; in British National Grid, \
or in ETRS89/WGS 84, converted with OSTN15).
<b>DEM</b>: the terrain in British National Grid with ODN heights.

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


class EstimateAlgorithm(Algorithm):
    def name(self):
        return "estimate"

    def displayName(self):  # noqa: N802 (the name QGIS calls)
        return "Estimate building heights from GNSS (4PL-B)"

    def shortHelpString(self):  # noqa: N802 (the name QGIS calls)
        return HELP

    def define(self):
        from gnss_citygml.model import METHODS
        from gnss_citygml.settings import (
            ANTENNA_HEIGHTS,
            CN0S,
            HEIGHT_RULES,
            MAX_RANGES,
            POSITION_DISTANCES,
            POSITION_SDS,
            RECEIVER_HEIGHTS,
            SIGNAL_MODELS,
            WINDOWS,
            Estimator,
            PositionError,
            Rays,
            ReceiverHeights,
        )

        double = QgsProcessingParameterNumber.Double
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
        self.addParameter(
            QgsProcessingParameterNumber(
                "MIN_ELEVATION",
                "Lowest satellite elevation (degrees)",
                double,
                Rays.min_elevation,
                minValue=0,
                maxValue=90,
            )
        )
        self.addParameter(
            QgsProcessingParameterNumber(
                "MAX_ELEVATION",
                "Highest satellite elevation (degrees)",
                double,
                Rays.max_elevation,
                minValue=0,
                maxValue=90,
            )
        )
        self.addParameter(
            QgsProcessingParameterEnum(
                "RECEIVER_HEIGHT",
                "Receiver height from",
                options=["the DEM + antenna height", "the observations' h (the log)"],
                defaultValue=RECEIVER_HEIGHTS.index(ReceiverHeights.source),
            )
        )
        self.addParameter(
            QgsProcessingParameterNumber(
                "ANTENNA_HEIGHT",
                "Antenna height above the ground (m)",
                double,
                ReceiverHeights.antenna_height,
                minValue=ANTENNA_HEIGHTS[0],
                maxValue=ANTENNA_HEIGHTS[1],
            )
        )
        self.addParameter(
            QgsProcessingParameterNumber(
                "INIT_THRESHOLD",
                "Initial C/N0 threshold (dB-Hz)",
                double,
                Estimator.init_threshold,
                minValue=CN0S[0],
                maxValue=CN0S[1],
            )
        )
        self.addParameter(choice("METHOD", "Method", METHODS, Estimator.method))
        self.addParameter(choice("HEIGHT_RULE", HEIGHT_RULE, HEIGHT_RULES, Estimator.height_rule))
        self.addParameter(
            advanced(choice("SIGNAL_MODEL", SIGNAL_MODEL, SIGNAL_MODELS, Estimator.signal_model))
        )
        self.addParameter(
            advanced(
                QgsProcessingParameterBoolean(
                    "LEVEL_PHONES", LEVEL_PHONES, defaultValue=Estimator.level_phones
                )
            )
        )
        self.addParameter(
            advanced(
                QgsProcessingParameterNumber(
                    "MAX_RANGE",
                    "Ray length (m)",
                    double,
                    Rays.max_range,
                    minValue=MAX_RANGES[0],
                    maxValue=MAX_RANGES[1],
                )
            )
        )
        self.addParameter(
            advanced(
                QgsProcessingParameterNumber(
                    "POSITION_SD",
                    "Receiver position error (m per axis; default: the observations', 1 m where "
                    "empty; 0: exact)",
                    double,
                    optional=True,
                    minValue=POSITION_SDS[0],
                    maxValue=POSITION_SDS[1],
                )
            )
        )
        self.addParameter(
            advanced(
                QgsProcessingParameterNumber(
                    "POSITION_DISTANCE",
                    "Position error of a moving receiver lasts for (m)",
                    double,
                    defaultValue=PositionError.distance,
                    minValue=POSITION_DISTANCES[0],
                    maxValue=POSITION_DISTANCES[1],
                )
            )
        )
        for name, description, (low, high) in (
            (
                "POSITION_WINDOW",
                "Instead: position error of a moving receiver lasts (s)",
                WINDOWS,
            ),
            (
                "CALIBRATION_SD",
                "Self-calibrate receiver offsets with prior (m; 4PL-B only)",
                POSITION_SDS,
            ),
            (
                "CALIBRATION_WINDOW",
                "One calibration offset per (s; default: per recording)",
                WINDOWS,
            ),
        ):
            self.addParameter(
                advanced(
                    QgsProcessingParameterNumber(
                        name, description, double, optional=True, minValue=low, maxValue=high
                    )
                )
            )
        self.addParameter(folder("GRID_DIR", "Folder with the OSTN15/OSGM15 grids"))
        self.addParameter(
            QgsProcessingParameterVectorDestination(
                "OUTPUT", "Heights", QgsProcessing.TypeVectorPolygon
            )
        )
        self.addOutput(QgsProcessingOutputNumber("BUILDINGS", "Buildings"))
        self.addOutput(QgsProcessingOutputNumber("CONVERGED", "Buildings with a height"))

    def job(self, parameters, context, feedback):
        from gnss_citygml.model import METHODS
        from gnss_citygml.settings import HEIGHT_RULES, RECEIVER_HEIGHTS, SIGNAL_MODELS

        number = self.parameterAsDouble
        optional = self.optional_number
        footprints, layer = self.parameterAsCompatibleSourceLayerPathAndLayerName(
            parameters, "FOOTPRINTS", context, ["gpkg", "fgb", "shp", "gml"], "gpkg", feedback
        )
        dem = self.parameterAsRasterLayer(parameters, "DEM", context)
        output = self.parameterAsOutputLayer(parameters, "OUTPUT", context)
        args = {
            "observations": self.parameterAsFile(parameters, "OBSERVATIONS", context),
            "footprints": footprints,
            "dem": dem.source(),
            "output": output,
            "layer": layer or None,
            "id_field": self.optional_text(parameters, "ID_FIELD", context),
            "rays": {
                "min_elevation": number(parameters, "MIN_ELEVATION", context),
                "max_elevation": number(parameters, "MAX_ELEVATION", context),
                "max_range": number(parameters, "MAX_RANGE", context),
            },
            "receiver_heights": {
                "source": RECEIVER_HEIGHTS[
                    self.parameterAsEnum(parameters, "RECEIVER_HEIGHT", context)
                ],
                "antenna_height": number(parameters, "ANTENNA_HEIGHT", context),
            },
            "estimator": {
                "method": self.chosen(parameters, "METHOD", METHODS, context),
                "init_threshold": number(parameters, "INIT_THRESHOLD", context),
                "height_rule": self.chosen(parameters, "HEIGHT_RULE", HEIGHT_RULES, context),
                "signal_model": self.chosen(parameters, "SIGNAL_MODEL", SIGNAL_MODELS, context),
                "level_phones": self.parameterAsBoolean(parameters, "LEVEL_PHONES", context),
            },
            "position_error": {
                "sd": optional(parameters, "POSITION_SD", context),
                "window": optional(parameters, "POSITION_WINDOW", context),
                "distance": number(parameters, "POSITION_DISTANCE", context),
            },
            "calibration": {
                "prior_sd": optional(parameters, "CALIBRATION_SD", context),
                "window": optional(parameters, "CALIBRATION_WINDOW", context),
            },
            "dem_crs": dem.crs().authid() or None,
            "grid_dir": self.optional_text(parameters, "GRID_DIR", context),
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
