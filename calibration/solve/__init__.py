"""The fits that join the camera and acoustic stages into a geometry.

The microphone solver with the cameras frozen (`solver`, the paper's equation 15; its
closed-form start `multilateration`; the paper's own search kept as a baseline,
`paper_method`), the joint optical-acoustic fit that refines cameras, board poses,
microphones, c and latencies together (`bundle`), the robust fitting helpers they and the
checks share (`robust`), and the Cramer-Rao bounds the fits are judged against (`crlb`).
"""
