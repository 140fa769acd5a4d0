"""Where independent or chained tasks run: the executors (a local process pool, or dask when
installed) and the scheduler that puts tasks on their lanes. Below crashnlp.optimize (profile
chains) and crashnlp.studies (a study's cases); the submodules load on first use, so that the
command line starts without them.
"""

CONNECT_TIMEOUT = 10.0  # s: how long a dask scheduler at --address may take to answer
DASK_EXTRA = "pip install 'crashnlp[dask]'"  # what brings dask.distributed, which --executor dask needs
