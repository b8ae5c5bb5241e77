"""Base parameters by weighted least squares (Sec. II-D, eqs. (16)-(19)): the regressor and its kernel, the base
parameters, the known joint terms, the (combined or sequential) estimation with its result, physical
consistency, how well the data determine M(q), and validation on held-out logs."""
