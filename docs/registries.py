"""Write femphase's registries (domain kinds, flows, time schemes, observables) into the
marked section of docs/scenes.md, from the entries' docstrings:

    python docs/registries.py            # rewrite docs/scenes.md
    python docs/registries.py --print    # print the tables

``tests/test_docs.py`` fails until the file says what the code registers.
"""

import argparse
from pathlib import Path

from femphase.registry import markdown, with_registries
from femphase.scene import registries

SCENES = Path(__file__).resolve().parent / "scenes.md"

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--print", action="store_true", help="print the tables instead of writing docs/scenes.md")
    if parser.parse_args().print:
        print(markdown(registries()))
    else:
        SCENES.write_text(with_registries(SCENES.read_text(), registries()))
