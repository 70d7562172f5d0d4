"""What a plan writes: plan.json, faces.npz and the CSV files (``report``), coverage.glb
(``glb``), preview.png and curve.png (``drawing``), per-element tables for IFC (``bim``)."""
