"""From Android GnssLogger logs and satellite orbits to the observations table.

``gnsslogger`` reads the logs, ``orbits`` reads SP3 precise orbits and RINEX navigation
files, ``sky`` turns satellite positions into azimuth and elevation per receiver epoch.
"""
