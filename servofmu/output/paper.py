"""The published numbers of Kiran, Sai Rama & Varadarajan (2013), Tables II and III, to set beside ours.

Rows follow results.paper_rows: G1 (first order) as pole / constant / DC gain / Fc+ / Fc−, G2 as its roots /
DC gain / Fc+ / Fc−.  Columns: the paper's target and the four methods it reports.
"""

__all__ = ["COLUMNS", "TABLES", "PAPER", "REFERENCES"]

PAPER = ("S. R. Kiran, T. Sai Rama, S. Varadarajan, \"PSO-ANN based hybrid technique for frequency domain "
         "identification of servo system with friction\", IJAREEIE 2(8), 2013")
# The paper's references whose methods fill its comparison columns: author, title, venue, year.
REFERENCES = {
    "31": "S. R. Kiran, S. Siva Nagaraju, S. Varadarajan, \"A hybrid technique for frequency domain identification "
          "of servo system with friction force\", International Journal of Engineering Science and Technology "
          "3(3):2020–2030, 2011 (GA-ANN: the hybrid with a genetic algorithm in place of PSO)",
    "2": "Y.-Y. Chen, P.-Y. Huang, J.-Y. Yen, \"Frequency-domain identification algorithms for servo systems with "
         "friction\", IEEE Transactions on Control Systems Technology 10(5):654–665, 2002 (the \"existing "
         "technique\": describing functions of the friction at two magnitudes; servofmu's chen2002)",
    "35": "S. R. Kiran, T. Sairama, S. Varadarajan, \"An adaptive hybrid technique for frequency domain "
          "identification of servo system with friction force\", International Review on Modelling and "
          "Simulations 6(1):235–245, 2013 (adaptive GA-ANN: crossover and mutation rates adapted to the fitness)",
}

COLUMNS = ("target", "GA-ANN [31]", "existing technique [2]", "adaptive GA-ANN [35]", "PSO-ANN (paper)")

TABLES = {
    "g1": {
        "pole": ("-10", "-10.2", "-10.1", "-10.0000", "-10.0006"),
        "constant": ("10", "9.8", "10.1", "10.0004", "10.0000"),
        "DC gain": ("1", "1.0", "0.9", "1.0000", "1.0008"),
        "Fc+": ("0.5", "0.5", "0.4", "0.5", "0.4995"),
        "Fc−": ("0.4", "0.3", "0.3", "0.4000", "0.4000"),
    },
    "g2": {
        "root 1": ("-2.5 + 31.52j", "-2.5381 + 31.518j", "-2.5714 + 30.525j", "-2.5009 + 31.5200j",
                   "-2.5004 + 31.5143j"),
        "root 2": ("-2.5 − 31.52j", "-2.5381 − 31.518j", "-2.5714 − 30.525j", "-2.5011 − 31.5190j",
                   "-2.501 − 31.5034j"),
        "root 3": ("-10", "-10.0211", "-10.1138", "-10.0015", "-10.0002"),
        "DC gain": ("1", "0.9989", "0.9903", "1.0000", "1.0000"),
        "Fc+": ("0.5", "0.4968", "0.4951", "0.4992", "0.5000"),
        "Fc−": ("0.4", "0.3957", "0.3941", "0.4000", "0.4000"),
    },
}
