"""EEVEE node groups that reconstruct the baked lightmaps, and their hook-up to materials."""
