"""A fake of forcedimension-core (modules dhd and drd) at the calls the adapter makes."""
