"""Many experiment sets at once, on a Dask cluster: ``phoid batch`` and ``identify_many``.

Modules: :mod:`phoid.batch.cluster` (a client to a running scheduler or a local cluster, a
map over items with a progress bar, the check for the ``phoid[batch]`` extra). Import the
names from their modules; dask, distributed, pandas and pyarrow are imported inside functions.
"""
