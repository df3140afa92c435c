"""What stands in for the water where there is none: the radio channel emulator
(`channel`: bit rate, delay, bit errors, losses in bursts) and the Water Linked
Modem-M64's model (`m64`) and its emulated pair on pseudo-terminals (`m64serial`)."""
