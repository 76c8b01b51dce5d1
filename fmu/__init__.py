"""FMI 2.0 co-simulation FMUs of hfdi's models, and an example master (fmpy).

* :mod:`fmu.slave`: the slave, a pythonfmu ``Fmi2Slave`` around ``hfdi.Integrator``;
* ``fmu/native/hfdi_fmi2.c``, ``hfdi_fmi3.c`` (on ``hfdi_fmu_core.h``) and :mod:`fmu.entry`: the FMU's native layer (the
  fmi2 functions) and its Python side;
* :mod:`fmu.build`: one FMU per model of ``hfdi.models`` (``python -m fmu build``);
* :mod:`fmu.master`: a co-simulation master on fmpy's low-level API;
* :mod:`fmu.metadata`: the units and labels written into the model descriptions.

Submodules are imported on demand: building needs pythonfmu, fmpy (the FMI
headers) and a C compiler, the master fmpy.
"""
