"""pyserial protocol handlers of the simulator (``printsim://``).

pyserial looks URL schemes up as ``<package>.protocol_<scheme>`` for every
package in ``serial.protocol_handler_packages``; importing :mod:`simulators`
adds this package to that list.
"""
