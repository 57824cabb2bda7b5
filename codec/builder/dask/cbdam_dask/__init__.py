"""Sharded cbdam builds on Dask distributed: each task runs a `cbdam shard` step as a subprocess.

`python -m cbdam_dask build INPUTS... -o OUT.cbdam --max-error E --scheduler local:W|tcp://H:P`
writes the repository `cbdam build` writes with the same arguments, byte for byte.
"""
