"""A fake of pyOpenHaptics (hd, hd_callback, hd_device) at the calls the adapter makes: the
servo callback runs in a scheduler thread at 1 kHz, positions in mm (row 3 of the
transform), forces in N."""
