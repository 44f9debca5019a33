"""Checks of the DCTL camcal writes: a syntax check, a numpy evaluator of the subset it emits, a C compile.

The subset (camcal.colour.export.dctl): ``//`` comments, one
``DEFINE_ACES_PARAM(...)`` line, ``__CONSTANT__ float NAME[N] = {...};``
arrays, ``__DEVICE__`` functions whose bodies are ``const float|int NAME =
EXPR;`` declarations and one ``return EXPR;``. Expressions use ``+ - * /``,
parentheses, float literals, ``(int)`` casts, array indexing and the calls
``_powf _fmaxf _fminf _floorf _fabs _copysignf make_float3`` and the file's own functions.
Anything else fails the parse: the evaluator is a reader of exactly what
camcal writes, not a C interpreter.
"""

import re
import subprocess
from dataclasses import dataclass, field

import numpy as np

BUILTINS = {"_powf": np.power, "_fmaxf": np.maximum, "_fminf": np.minimum, "_floorf": np.floor, "_fabs": np.abs,
            "_copysignf": np.copysign,
            "make_float3": lambda r, g, b: np.stack(np.broadcast_arrays(r, g, b), axis=-1),
            "_int": lambda x: np.asarray(x).astype(np.int64)}
_ARRAY = re.compile(r"__CONSTANT__ float (\w+)\[(\d+)\] = \{([^}]*)\};")
_FUNCTION = re.compile(r"__DEVICE__ (float3|float) (\w+)\(([^)]*)\)\n\{\n(.*?)\n\}", re.S)
_DECLARATION = re.compile(r"const (float|int) (\w+) = (.+)")
_FLOAT = re.compile(r"(?<![\w.])(\d+\.\d*(?:e[+-]?\d+)?|\d+e[+-]?\d+)f\b")
_TOKEN = re.compile(r"\s*(?:(\d+(?:\.\d*)?(?:e[+-]?\d+)?)|(\w+)|([-+*/(),\[\]]))")


@dataclass
class Program:
    arrays: dict = field(default_factory=dict)
    functions: dict = field(default_factory=dict)  # name -> (parameter names, [(name or None, python expr)])
    aces_param: bool = False


def _strip_comments(text):
    return "\n".join(line.split("//", 1)[0].rstrip() for line in text.splitlines())


def _python_expression(expression, known):
    """C expression of the subset -> Python text; every identifier must be in ``known``."""
    text = _FLOAT.sub(r"\1", expression.strip())
    text = re.sub(r"\(int\)\s*(\w+)", r"_int(\1)", text)
    position = 0
    while position < len(text):
        match = _TOKEN.match(text, position)
        if not match or match.end() == position:
            raise SyntaxError(f"unexpected text in DCTL expression: {text[position:]!r}")
        name = match.group(2)
        if name is not None and not name.isdigit() and name not in known and name not in BUILTINS:
            raise NameError(f"undeclared identifier {name!r} in {expression!r}")
        position = match.end()
    return text


def parse(text):
    """The :class:`Program` of a DCTL camcal wrote (raises on anything outside the subset)."""
    code = _strip_comments(text)
    program = Program(aces_param="DEFINE_ACES_PARAM(IS_PARAMETRIC_ACES_TRANSFORM: 0)" in code)
    code = code.replace("DEFINE_ACES_PARAM(IS_PARAMETRIC_ACES_TRANSFORM: 0)", "")
    for name, size, body in _ARRAY.findall(code):
        values = np.array([float(v.strip().removesuffix("f")) for v in body.split(",") if v.strip()])
        assert values.size == int(size), f"array {name}: {values.size} values for [{size}]"
        program.arrays[name] = values
    code = _ARRAY.sub("", code)
    for _, name, parameters, body in _FUNCTION.findall(code):
        params = [p.split()[-1] for p in parameters.split(",")]
        known = set(params) | set(program.arrays) | set(program.functions)
        statements = []
        for statement in filter(None, (s.strip() for s in body.split(";"))):
            declared = _DECLARATION.fullmatch(statement)
            if declared:
                statements.append((declared.group(2), _python_expression(declared.group(3), known)))
                known.add(declared.group(2))
            elif statement.startswith("return "):
                statements.append((None, _python_expression(statement.removeprefix("return "), known)))
            else:
                raise SyntaxError(f"statement outside camcal's DCTL subset: {statement!r}")
        assert statements and statements[-1][0] is None, f"function {name} does not end with a return"
        program.functions[name] = (params, statements)
    leftover = _FUNCTION.sub("", code).strip()
    assert not leftover, f"text outside arrays and functions: {leftover[:80]!r}"
    return program


def evaluate(program, codes):
    """``transform(p_R, p_G, p_B)`` of the program on ``(N, 3)`` code values, in float64 numpy."""
    scope = dict(BUILTINS, **program.arrays)

    def function(params, statements):
        def call(*args):
            local = dict(scope, **dict(zip(params, args)))
            for name, expression in statements:
                value = eval(expression, {"__builtins__": {}}, local)  # the subset's arithmetic, checked by parse
                if name is None:
                    return value
                local[name] = value
        return call

    for name, (params, statements) in program.functions.items():
        scope[name] = function(params, statements)
    codes = np.asarray(codes, dtype=np.float64)
    return scope["transform"](0, 0, 0, 0, codes[:, 0], codes[:, 1], codes[:, 2])


def syntax_problems(text):
    """What a C reader would refuse: unbalanced braces / parentheses, a statement without ``;``."""
    code = _strip_comments(text)
    problems = []
    for open_, close in ("{}", "()", "[]"):
        depth = 0
        for char in code:
            depth += (char == open_) - (char == close)
            if depth < 0:
                break
        if depth != 0:
            problems.append(f"unbalanced {open_}{close}")
    depth, initialiser = 0, False
    for number, line in enumerate(code.splitlines(), 1):
        stripped = line.strip()
        if stripped.endswith("= {"):
            initialiser = True
        elif stripped == "};":
            initialiser = False
        elif depth > 0 and not initialiser and stripped not in ("", "{", "}") and not stripped.endswith(";"):
            problems.append(f"line {number} does not end a statement with ';': {stripped[:60]!r}")
        depth += stripped.count("{") - stripped.count("}")
    return problems


PRELUDE = """
#include <math.h>
#include <stdio.h>
typedef struct { float x, y, z; } float3;
static float3 make_float3(float x, float y, float z) { float3 v = {x, y, z}; return v; }
#define __DEVICE__ static
#define __CONSTANT__ static const
#define DEFINE_ACES_PARAM(...)
#define _powf powf
#define _fmaxf fmaxf
#define _fminf fminf
#define _floorf floorf
#define _fabs fabsf
#define _copysignf copysignf
"""

MAIN = """
int main(void) {
    float r, g, b;
    while (scanf("%f %f %f", &r, &g, &b) == 3) {
        float3 v = transform(1, 1, 0, 0, r, g, b);
        printf("%.9g %.9g %.9g\\n", v.x, v.y, v.z);
    }
    return 0;
}
"""


def compile_and_run(text, codes, folder, cc="cc"):
    """Compile the DCTL as C99 (warnings are errors) with a prelude for Resolve's names; run it on ``codes``."""
    source, binary = folder / "dctl_check.c", folder / "dctl_check"
    source.write_text(PRELUDE + text + MAIN)
    build = subprocess.run([cc, "-std=c99", "-Wall", "-Werror", "-Wno-unused-parameter", "-Wno-unused-function",
                            "-O1", "-o", str(binary), str(source), "-lm"], capture_output=True, text=True)
    assert build.returncode == 0, build.stderr
    lines = "\n".join(" ".join(f"{v:.9g}" for v in row) for row in np.asarray(codes, dtype=np.float64))
    run = subprocess.run([str(binary)], input=lines + "\n", capture_output=True, text=True, check=True)
    return np.array([[float(v) for v in line.split()] for line in run.stdout.splitlines()])
