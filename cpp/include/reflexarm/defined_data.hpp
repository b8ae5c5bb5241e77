// reflexarm: pinocchio::Data (and Eigen::LLT members) without indeterminate enums, for the Controller's and the
// ContactIsolator's members.
//
// Pinocchio's Data constructors never compute its two Eigen::LLT members (llt_JMinvJt, osim_llt), and Eigen's LLT
// leaves m_info indeterminate until compute(): copying such a Data (its copy constructor or assignment, so a
// Controller's) reads that enum (UBSan -fsanitize=enum: "not a valid value for type 'ComputationInfo'"). A compute()
// on an empty matrix defines it (Success) without allocating; the LLTs stay 0x0, and every Pinocchio algorithm that
// uses them (contact dynamics, PV; none of ours) computes them first.
#pragma once

#include <new>

#include "pinocchio/multibody.hpp"

namespace reflexarm
{

  inline void defineLlts(pinocchio::Data & data) noexcept
  {
    data.llt_JMinvJt.compute(pinocchio::Data::MatrixXs());
    data.osim_llt.compute(pinocchio::Data::MatrixXs());
  }

  /// An Eigen::LLT of n x n matrices whose m_info is defined, for LLT members of our own (the same indeterminate enum
  /// as above when a default or size-constructed LLT is copied): computed on the n x n identity (Success), so its
  /// storage is sized here and a later compute() of an n x n matrix does not allocate.
  template <typename Llt> inline Llt definedLlt(Eigen::Index n)
  {
    Llt llt(n);
    llt.compute(Llt::MatrixType::Identity(n, n));
    return llt;
  }

  /// A default Data with defined LLTs (the default of a Data member).
  inline pinocchio::Data definedData()
  {
    pinocchio::Data data;
    defineLlts(data);
    return data;
  }

  /// data = Data(model) without a copy: destroyed and constructed in place, its LLTs defined. If the constructor
  /// throws, data is left a default Data (so its owner's destructor finds an object) and the exception goes on.
  inline void constructData(pinocchio::Data & data, const pinocchio::Model & model)
  {
    using Data = pinocchio::Data;
    data.~Data();
    try
    {
      new (&data) Data(model);
    }
    catch (...)
    {
      new (&data) Data();
      defineLlts(data);
      throw;
    }
    defineLlts(data);
  }

} // namespace reflexarm
