"""Independent reference implementations, written from the definitions in numpy/scipy, that
the tests check the product against. The studies (studies/) use them too, so the figures they
report come from tested code.

The tests import them as ``oracles.<module>``: pytest puts tests/python, the first folder above
a test file without an ``__init__.py``, on ``sys.path`` (its default "prepend" import mode).
"""
