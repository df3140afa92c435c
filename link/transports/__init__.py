"""Transports for link frames: UDP, serial and in-process (`transport`), the Water
Linked Modem-M64 (`wlmodem`), and the URL that names one (`urls.open_transport`)."""
