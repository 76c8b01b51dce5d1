"""FMI 2.0 co-simulation FMUs of hfdi's models (pythonfmu), and an example master (fmpy).

* :mod:`fmu.slave`: the slave, a pythonfmu ``Fmi2Slave`` around ``hfdi.Integrator``;
* :mod:`fmu.build`: one FMU per model of ``hfdi.models`` (``python -m fmu build``);
* :mod:`fmu.master`: a co-simulation master on fmpy's low-level API;
* :mod:`fmu.metadata`: the units and labels written into the model descriptions.

Submodules are imported on demand: building needs pythonfmu, the master fmpy.
"""
