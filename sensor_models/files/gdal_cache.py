"""GDAL's raster block cache, capped where gcpcal reads or writes a large raster by blocks.

GDAL keeps decoded blocks in one process-wide cache (5 % of the RAM by default): a decimated
read of a large raster, or a file written block by block until it closes, would fill it. The
stages that do so set it with ``rasterio.Env(GDAL_CACHEMAX=GDAL_BLOCK_CACHE_BYTES)``.

Rasterio takes an integer ``GDAL_CACHEMAX`` as **bytes** (GDAL's own configuration option reads
small numbers as megabytes): ``GDAL_CACHEMAX=64`` through rasterio is a 64-byte cache, which
holds no block, so every block is decoded again for each line that needs it. Measured on the
1024-line simulator bench's 3 935 x 8 867 px deflate DOM (256 px tiles), the decimated read of
its brightness scale (512 x 512 px, nearest): 6.4-6.7 s at 64 bytes, 0.23-0.26 s at 64 MiB,
the same pixels.
"""

from __future__ import annotations

__all__ = ["GDAL_BLOCK_CACHE_BYTES"]

#: The cap, bytes (64 MiB): what a block-by-block read or write holds at most besides its blocks.
GDAL_BLOCK_CACHE_BYTES = 64 << 20
