"""Map rasters: reference orthoimages (DOMs), their products, mosaics and quality bands."""
