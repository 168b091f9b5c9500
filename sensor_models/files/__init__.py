"""File primitives every room uses: documents read with size and encoding checks, outputs written whole or not at all, and the thread count of the parallel stages."""
