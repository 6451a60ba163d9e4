"""Plant description files made by code for the tests (sizes, hostile text, fuzzing)."""


def diagonal_device(n: int, name: str = "Diag", mass: str = "m{i}*(1 + q{i}**2)") -> str:
    """A TOML description of n decoupled maglev-like axes (M, Psi, R's diagonal); `mass` the entry M_ii."""
    def diag(entries):
        return "[" + ", ".join("[" + ", ".join(entries[i] if i == j else "0" for j in range(n)) + "]" for i in range(n)) + "]"
    def v(k, unit, what):
        return "[" + ", ".join(f'["{k}{i}", "{unit}", "{what} {i}"]' for i in range(n)) + "]"
    pars = "\n".join(f'm{i} = [0.1, "kg", "mass", "> 0"]\nk{i} = [0.6, "H.m", "inductance", "> 0"]\n'
                     f'c{i} = [0.005, "m", "magnet", "> 0"]\nb{i} = [0.8, "N", "weight", "> 0"]' for i in range(n))
    return f'''name = "{name}"
description = "{n} decoupled axes"
[variables]
q = {v("q", "m", "position")}
p = {v("p", "kg.m/s", "momentum")}
x_e = {v("x", "Wb", "flux")}
u = {v("u", "V", "voltage")}
[parameters]
{pars}
R = [2.0, "Ohm", "resistance", "> 0"]
[model]
M = {diag(['"' + mass.format(i=i) + '"' for i in range(n)])}
V = "{' + '.join(f'b{i}*q{i}' for i in range(n))}"
Psi = {diag([f'"(c{i} - q{i})/k{i}"' for i in range(n)])}
R_m = {diag(['"R"'] * n)}
J_e = {diag(['"0"'] * n)}
R_e = {diag(['"R"'] * n)}
G_e = {diag(['"1"'] * n)}
domain = [{", ".join(f'"q{i} < c{i}"' for i in range(n))}]
'''
