"""Locating stage: ranges (`ranging`), least squares (`lsq`), multilateration (`multilat`),
camera pose (`pose`), pose + Kalman per device (`posefilter`, `kalman`), the indoor positioner
(`indoor`) and its prediction of where the map's lights appear next (`map_prior`), the vehicle locator (`vehicle`: host placement `vehicle_host`, cars ahead
`vehicle_cars`, map-aided association `vehicle_assoc`, pair ranging `vehicle_ranging`; its road
filter `road_kalman`).
"""
