// The tick's inputs and outputs in reflexarm._core, through NumPy's C API (core.cpp is its only user: NumPy's
// API table is a static of this translation unit, filled by importNumpy() when the module loads).
//
// Inputs: an exact numpy.ndarray that is one-dimensional, native float64, C-contiguous and aligned is read in
// place from its fields (a few ns); any other object goes through the buffer protocol (C-contiguous,
// one dimension, format "d", ~0.1 us per vector), as before; anything else is refused (the caller converts
// once or raises). Both paths read the same memory, never a copy.
// Outputs: new float64 arrays that own their data (the Command's tau and residual; users keep them).
#pragma once

#define NPY_NO_DEPRECATED_API NPY_2_0_API_VERSION
#include <Python.h>
#include <numpy/arrayobject.h>
#include <numpy/arrayscalars.h>

#include <cstring>

#include <Eigen/Core>
#include <nanobind/nanobind.h>

namespace reflexarm_bindings
{
  namespace nb = nanobind;
  using Map = Eigen::Map<const Eigen::VectorXd>;

  /// Loads NumPy's C API table (once, at module import).
  inline void importNumpy()
  {
    if (_import_array() < 0)
      throw nb::python_error();
  }

  /// The eight vectors of a tick (q, dq, tau_m, wrench, gravity, q_d, dq_d, ddq_d), read without copies.
  class TickInputs
  {
  public:
    static constexpr int kCount = 8;

    TickInputs() = default;
    ~TickInputs() { release(); }
    TickInputs(const TickInputs &) = delete;
    TickInputs & operator=(const TickInputs &) = delete;

    /// Reads the objects; false (nothing held) if one is neither a plain float64 array nor a float64 buffer.
    bool read(PyObject * const * objects) noexcept
    {
      for (int i = 0; i < kCount; ++i)
        if (!readOne(objects[i], i))
        {
          release();
          return false;
        }
      return true;
    }

    Map operator[](int i) const { return Map(data_[i], static_cast<Eigen::Index>(size_[i])); }

  private:
    bool readOne(PyObject * o, int i) noexcept
    {
      if (Py_TYPE(o) == &PyArray_Type)
      {
        auto * a = reinterpret_cast<PyArrayObject *>(o);
        if (PyArray_NDIM(a) == 1 && PyArray_TYPE(a) == NPY_DOUBLE && PyArray_ISNOTSWAPPED(a)
            && PyArray_IS_C_CONTIGUOUS(a) && PyArray_ISALIGNED(a))
        {
          data_[i] = static_cast<const double *>(PyArray_DATA(a));
          size_[i] = PyArray_DIM(a, 0);
          return true;
        }
      }
      Py_buffer & v = views_[i];
      if (PyObject_GetBuffer(o, &v, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) != 0)
      {
        PyErr_Clear();
        return false;
      }
      held_[i] = true;
      const bool ok = v.ndim == 1 && v.itemsize == 8 && v.format != nullptr
                      && (std::strcmp(v.format, "d") == 0 || std::strcmp(v.format, "=d") == 0);
      data_[i] = static_cast<const double *>(v.buf);
      size_[i] = ok ? v.shape[0] : 0;
      return ok;
    }

    void release() noexcept
    {
      for (int i = 0; i < kCount; ++i)
        if (held_[i])
        {
          PyBuffer_Release(&views_[i]);
          held_[i] = false;
        }
    }

    const double * data_[kCount] = {};
    Py_ssize_t size_[kCount] = {};
    Py_buffer views_[kCount];
    bool held_[kCount] = {};
  };

  /// A new one-dimensional float64 array owning a copy of `v` (a new reference; nullptr with a Python error
  /// set if the allocation failed).
  inline PyObject * newArrayCopy(const Eigen::VectorXd & v) noexcept
  {
    npy_intp n = static_cast<npy_intp>(v.size());
    // the built-in float64 descriptor (a new reference, which PyArray_NewFromDescr steals)
    PyObject * out = PyArray_NewFromDescr(&PyArray_Type, PyArray_DescrFromType(NPY_DOUBLE), 1, &n, nullptr,
                                          nullptr, 0, nullptr);
    if (out != nullptr && n > 0)
      std::memcpy(PyArray_DATA(reinterpret_cast<PyArrayObject *>(out)), v.data(), sizeof(double) * v.size());
    return out;
  }

  /// Reads a time stamp that is a Python float or a numpy.float64 into `t`; false for anything else (which the
  /// Python side converts or refuses).
  inline bool readFloat(PyObject * o, double & t) noexcept
  {
    if (PyFloat_CheckExact(o))
      t = PyFloat_AS_DOUBLE(o);
    else if (Py_TYPE(o) == &PyDoubleArrType_Type)
      t = PyArrayScalar_VAL(o, Double);
    else
      return false;
    return true;
  }
} // namespace reflexarm_bindings
