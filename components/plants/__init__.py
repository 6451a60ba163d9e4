"""The paper's plants as descriptions (*.toml) and the model modules generated from them (*_model.py,
python -m components.codegen)."""
