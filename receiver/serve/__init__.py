"""Lighting server (thesis 4.3-4.4): the datagram format both ends share (`wire`), the UDP
server (`server`) and the device-side client (`client`).
"""
