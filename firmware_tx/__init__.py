"""occloc LED driver: on-air encoder, waveform scheduler, pin backends, serial control.

Every module here runs unchanged on MicroPython (1.27+) and CPython: no dataclasses, no
typing, no f-string-only features beyond what MicroPython supports, only bytearray/array/ints.
"""

VERSION = "1.0.0"
