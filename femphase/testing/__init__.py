"""Test harnesses that tests/ and benchmarks/ import (never the solver itself).

``fuzzing``  bad inputs of ``femphase run``, each checked for one clear message and an
             untouched run directory
``faults``   kill campaigns: a real run killed again and again and resumed, checked for
             outputs bit-identical to an uninterrupted run
"""
