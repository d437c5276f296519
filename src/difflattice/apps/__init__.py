"""Applications built on the library, reached through the `difflattice` command: the demo, the
paper's gallery, accuracy studies, validation measurements, scene runs with their outputs.

Library modules never import from here."""
