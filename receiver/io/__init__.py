"""Files and devices: camera file (`camera`), LED map (`ledmap`), frame sources (`sources`),
JSON Lines output (`output`), truth and run files (`truth`), the LED driver's serial link (`txlink`).
"""
