"""From Android GnssLogger logs and satellite orbits to the observations table.

``gnsslogger`` reads the logs (``logrecords`` splits and checks their lines, ``measurements``
says what the fields mean), ``positions`` gives the receiver's position at each epoch (from the
log's fixes or a survey), ``orbits`` gives satellite positions from SP3 precise orbits
(``sp3``) or RINEX navigation files (``navigation``, propagated by ``propagation``; both read
through ``orbitfile``), ``gpstime`` converts between GPS time and UTC, ``sky`` turns satellite
positions into azimuth and elevation per receiver epoch, and ``observe`` puts them together.
"""
