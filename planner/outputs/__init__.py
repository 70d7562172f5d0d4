"""What a plan writes: a :class:`~planner.pipeline.PlanResult` in, files out.

plan.json, faces.npz and the CSV files (``report``, canonical JSON in ``canonical``),
coverage.glb (``glb``), preview.png and curve.png (``drawing``), the print set plan.pdf
(``printset``), per-element tables for IFC (``bim``), plan.ifc (``ifc_plan``), plan.bcf
(``bcf_plan``) and plan.dxf (``cad``), the last three from what ``stations`` shares.
"""
