"""Reading models: a file in, a :class:`~planner.scene.Scene` out.

Takes a model file (OBJ, PLY, STL, OFF, GLB/glTF through trimesh: ``readers``; IFC through
IfcOpenShell: ``ifc``, with its storeys, rooms and element classes) and the reading
parameters (``unit_scale``, ``up_axis``, ``max_edge_m``); gives the scene in metres, Z up
(``orientation`` finds and applies the up axis). Nothing here plans: the candidates in an
IFC model's rooms are made by :mod:`planner.candidates.rooms`.
"""
