"""Information-rich excitation: parameter sensitivities, Fisher information, optimal design."""
