"""Shape families, registered by name in ``physdyn.registry.SHAPE_FAMILIES``.

Importing this package registers the built-ins.
"""
