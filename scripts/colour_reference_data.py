"""Writes the colorimetry reference tables of processing/data and the CIEDE2000 test pairs
from the colour-science package (0.4.7; see processing/data/README.md)."""
import ast, os, sys
import numpy as np
import colour

grid = np.arange(390, 731, 10)
out = sys.argv[1]
shape = colour.SpectralShape(390, 730, 10)

def write(name, header, rows):
    with open(os.path.join(out, name), "w") as f:
        f.write(header + "\n")
        for r in rows:
            f.write(",".join(r) + "\n")

cmf = colour.MSDS_CMFS["CIE 1964 10 Degree Standard Observer"]
write("cie1964_10deg_cmf_390_730_10nm.csv", "wavelength_nm,xbar,ybar,zbar",
      [[f"{w:.0f}"] + [f"{v:.6g}" for v in cmf[w]] for w in grid])
for key, name in [("D65", "cie_illuminant_d65_390_730_10nm.csv"), ("D50", "cie_illuminant_d50_390_730_10nm.csv")]:
    sd = colour.SDS_ILLUMINANTS[key]
    write(name, "wavelength_nm,relative_power", [[f"{w:.0f}", f"{sd[w]:.6g}"] for w in grid])

# Sharma, Wu and Dalal (2005) CIEDE2000 test pairs as colour-science's tests carry them.
import colour.difference.tests.test_delta_e as t
src = open(t.__file__).read()
start = src.index("def test_delta_E_CIE2000_Sharma2004")
body = src[start:src.index("class TestDelta_E_CMC")]
def block(name):
    i = body.index(name + " = np.array(")
    j = body.index("\n        )", i)
    text = body[i:j]
    # keep commented rows (the pair colour-science skips) in order
    text = text.replace("# [", "[").replace("# 4.8045", "4.8045")
    return ast.literal_eval(text[text.index("(") + 1:].strip().rstrip(","))
l1, l2, de = block("Lab_1"), block("Lab_2"), block("d_E")
assert len(l1) == len(l2) == len(de) == 34, (len(l1), len(l2), len(de))
write(sys.argv[2], "pair,L1,a1,b1,L2,a2,b2,delta_e00",
      [[str(i + 1)] + [f"{v:.4f}" for v in a + b] + [f"{d:.4f}"] for i, (a, b, d) in enumerate(zip(l1, l2, de))])
print(colour.__version__)
