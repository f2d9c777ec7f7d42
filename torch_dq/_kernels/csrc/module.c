/* The Python module of the compiled kernels: empty. Its functions are plain C, called
 * through ctypes (torch_dq/_kernels/native.py); this entry only lets the shared library be
 * found and imported as torch_dq._kernels._native. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

static struct PyModuleDef native_module = {
    PyModuleDef_HEAD_INIT, "_native",
    "Compiled kernels of torch_dq, called through ctypes.", -1, NULL,
};

PyMODINIT_FUNC PyInit__native(void) { return PyModule_Create(&native_module); }
