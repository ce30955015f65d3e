"""One physics idea per @ti.func; the solvers compose them."""
