"""Names and colour words for synthetic landmarks and streets (invented, generic)."""

from __future__ import annotations

RESTAURANTS = (
    "Golden Wok",
    "Blue Door Diner",
    "Mama Rosa's Pizzeria",
    "Sakura Sushi",
    "Taco Loco",
    "The Green Fork",
    "Burger Barn",
    "Saffron Kitchen",
    "Harbor Fish House",
    "Little Lisbon Grill",
    "Pho Saigon",
    "Corner Bistro",
    "Red Lantern",
    "Smokehouse BBQ",
    "Cafe Aurora",
    "Noodle Bar 88",
)
CHURCHES = (
    "St. Mary's Church",
    "Grace Chapel",
    "Trinity Church",
    "St. Peter's Cathedral",
    "Hope Chapel",
)
STADIUMS = ("Riverside Stadium", "Memorial Stadium", "Eagle Arena", "City Stadium")
GAS_STATIONS = ("Sunrise Gas", "Metro Fuel", "Express Gas Station", "Cityline Fuel", "Route 9 Gas")
PARKS = (
    "Willow Park",
    "Lincoln Park",
    "Cedar Grove Park",
    "Harmony Park",
    "Maple Commons",
    "Elm Green",
)
SCHOOLS = ("Jefferson High School", "Oakridge Elementary School", "Westside Academy")
HOSPITALS = ("St. Luke's Hospital", "City General Hospital", "Northside Medical Center")
MALLS = ("Westgate Mall", "Union Square Shopping Center", "Riverview Plaza")
HOTELS = ("Grand Plaza Hotel", "Harbor View Hotel", "The Meridian Inn")
TOWERS = ("Harbor Tower", "Summit Tower", "Skyline Center")
ROUNDABOUTS = ("Fountain Circle", "Liberty Roundabout", "Market Circle")
BRIDGES = ("Old Stone Bridge", "Iron Bridge", "Mill Street Bridge", "Union Bridge")
STREETS = (
    "Oak Street",
    "Maple Avenue",
    "Pine Street",
    "Cedar Road",
    "Elm Street",
    "Washington Avenue",
    "Park Road",
    "Lake Street",
    "Hill Street",
    "Main Street",
    "River Road",
    "Church Street",
    "Market Street",
    "Mill Road",
    "Station Road",
    "King Street",
    "Queen Street",
    "Bridge Street",
)

#: Roof colours (BGR) and the word a person would use for each.
ROOF_COLOURS: tuple[tuple[tuple[int, int, int], str], ...] = (
    ((58, 62, 176), "red"),
    ((70, 105, 190), "orange"),
    ((74, 88, 150), "brown"),
    ((205, 210, 212), "white"),
    ((168, 170, 168), "light gray"),
    ((92, 94, 96), "dark gray"),
    ((150, 110, 60), "blue"),
    ((88, 128, 88), "green"),
    ((150, 185, 200), "beige"),
    ((48, 50, 52), "black"),
)
