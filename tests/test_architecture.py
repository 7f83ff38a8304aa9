"""The worked examples of docs/architecture.md run as written: a new flow, a new energy
term, a new observable and a new time scheme, each registered, used by a scene and checked."""

import re
from pathlib import Path

from femphase.analysis.observables import OBSERVABLES
from femphase.flows import FLOWS
from femphase.timestepping.base import SCHEMES

DOC = Path(__file__).resolve().parents[1] / "docs" / "architecture.md"


def test_the_worked_examples_of_the_architecture_guide_run():
    blocks = re.findall(r"```python\n(.*?)```", DOC.read_text(), flags=re.S)
    assert len(blocks) >= 8
    namespace: dict = {}
    try:
        exec(compile("\n".join(blocks), str(DOC), "exec"), namespace)  # noqa: S102 (our own docs)
    finally:  # the registries are global: leave them as the other tests expect them
        for registry, name in ((FLOWS, "plug"), (OBSERVABLES, "phi_range"), (SCHEMES, "euler-strang")):
            if name in registry:
                registry.unregister(name)
    assert "Sedimentation" in namespace
